"""What a batch takes: the conversion options with the machine by name (picklable, hashable for the
manifest).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from doodlecam import __version__
from doodlecam.options import ConvertOptions


@dataclass(frozen=True, kw_only=True)
class BatchOptions(ConvertOptions):
    """Everything ``convert`` takes, as plain picklable values: the machine by name.

    ``settings()`` builds the pipeline's ``Settings`` (importing the pipeline),
    which only workers do.
    """

    machine: str = "doodlebot"

    def __post_init__(self):
        from doodlecam import registry

        super().__post_init__()
        for key, value in registry.canonical_fields(self).items():  # the manifest hashes the plugins' own names
            object.__setattr__(self, key, value)

    def settings(self):
        from doodlecam.machine import load_machine
        from doodlecam.pipeline import Settings

        # the same fields as Settings, copied (asdict copies the dicts), the profile loaded
        return Settings(**{**dataclasses.asdict(self), "machine": load_machine(self.machine)})

    def fingerprint(self) -> str:
        """Hash of everything that changes the outputs: options, the machine profile as
        parsed, drop-in plugin sources and the doodlecam version."""
        from doodlecam.machine import load_machine

        machine = dataclasses.asdict(load_machine(self.machine))
        machine.pop("source", None)  # where the profile lives does not change the output
        plugin_sources = {}
        for d in self.plugin_dirs:
            for p in sorted(Path(d).glob("*.py")):
                plugin_sources[str(p)] = hashlib.blake2b(p.read_bytes(), digest_size=16).hexdigest()
        blob = {
            "doodlecam": __version__,
            "options": {k: v for k, v in dataclasses.asdict(self).items() if k not in ("machine", "plugin_dirs")},
            "machine": machine,
            "plugins": plugin_sources,
        }
        text = json.dumps(blob, sort_keys=True, default=str)
        return hashlib.blake2b(text.encode(), digest_size=16).hexdigest()
