"""``python -m doodlecam`` is the ``doodlecam`` command."""

from .cli import entry

entry()
