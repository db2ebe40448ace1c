"""EiBotBoard post: the exact command stream an AxiDraw's board receives (``.ebb``).

One ``LM`` (constant acceleration per motor, whole steps) per velocity-sample period
while drawing (a motor that reverses inside a period turns back inside its LM on firmware 3.0;
``firmware=2.7`` splits such a period in two for older boards), constant-acceleration ``LM`` moves for pen-up travel, ``SP`` with the
profile's pen delays, ``SC`` for the servo, ``@PAUSE,<pen>`` where the pen is changed.
The writer lives in ``doodlecam.link.ebb.stream``; docs/ebb.md describes the file.
"""

from __future__ import annotations

from typing import Any

from doodlecam.api import Option, PostProcessor


class EbbPost(PostProcessor):
    name = "ebb"
    summary = "EiBotBoard (AxiDraw) command stream: one LM per sample period, exact steps (docs/ebb.md)"
    extension = ".ebb"
    options = (
        Option("servo_up", int, 20641, "SC,4: pen-up servo position (units of 83.3 ns)"),
        Option("servo_down", int, 15248, "SC,5: pen-down servo position (units of 83.3 ns)"),
        Option("servo_rate_up", int, 0, "SC,11: servo speed going up (0 = leave the board's setting)"),
        Option("servo_rate_down", int, 0, "SC,12: servo speed going down (0 = leave the board's setting)"),
        Option("lift_clear", float, 0.0, "s after a lift starts when the pen is off the paper: travel starts then and "
               "overlaps the rest of the lift (SP,1 waits this long; the AxiDraw driver's negative pen_delay_up); "
               "0 = wait the pen's whole up_delay"),
        Option("firmware", str, "3.0", "oldest EBB firmware the file must run on: 3.0 (a motor reverses inside one LM, "
               "at most one LM per sample period) or 2.7 (older boards: such a period is split in two LMs)",
               choices=("3.0", "2.7")),
    )

    def write(self, job, options: dict[str, Any]) -> bytes:
        from doodlecam import registry
        from doodlecam.errors import OutputError
        from doodlecam.link.ebb.stream import write_ebb

        for key in ("servo_up", "servo_down"):
            if not 1 <= options[key] <= 65535:
                raise OutputError(f"post ebb: {key} must be 1..65535 (SC takes 16-bit values), got {options[key]}")
        if not 0.0 <= options["lift_clear"] <= 60.0:
            raise OutputError(f"post ebb: lift_clear must be 0..60 s, got {options['lift_clear']:g}")
        return write_ebb(job, registry.kinematics_for(job.machine), options)
