"""``python -m doodlecam`` is the ``doodlecam`` command."""

from doodlecam.cli import entry

entry()
