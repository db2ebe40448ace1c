"""PLC packet file post-processor: the report's header + command list.

A minimal post-processor, and the one to copy when writing your own: subclass
``PostProcessor``, set ``name``, ``summary``, ``extension`` and ``options``,
and return the file's bytes from ``write``. Register it under the
``doodlecam.postprocessors`` entry-point group (see pyproject.toml).
"""

from __future__ import annotations

from typing import Any

from doodlecam.api import Option, PostProcessor


class PlcPost(PostProcessor):
    name = "plc"
    summary = "PLC packet file: header + MOVE/DRAW velocity-sample commands (docs/formats.md)"
    extension = ".plc"
    options: tuple[Option, ...] = ()  # the format is fixed; the machine profile sets everything

    def write(self, job, options: dict[str, Any]) -> bytes:
        from doodlecam.link.plc.packetfile import commands_array, write_plc

        # The array form skips building one Python object per command.
        return write_plc(*commands_array(job))
