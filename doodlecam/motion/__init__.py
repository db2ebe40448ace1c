"""Motion design after Kirecci, *Motion design for high-speed machines*.

* ``laws``       – the thesis's cam laws (§2.7): position, velocity,
                   acceleration and jerk of a rise h over a duration T.
* ``polynomial`` – power-form polynomials through design points (eq. 3.1–3.6)
                   and polynomials with arbitrary real powers (§3.6), whose
                   powers an optimiser can choose.
* ``envelope``   – the tolerance envelope and meandering checks (§3.5, §4.7).
* ``design``     – MOTDES-style multi-segment, multi-axis design from TOML
                   (chapter 5), actuator-limit and workspace checks.
* ``export``     – the MOTDES table (pos, vel, acc, jerk; 300 rows) and plots.
* ``ilc``        – iterative learning control with the windowed FIR filter
                   (§7.2.3, eq. 7.6–7.12).
* ``servo``      – a simulated servo axis to show what learning control does.

Units: mm and s (a design may use any length unit; the actuator check assumes
mm). Nothing here is imported by ``doodlecam --help``.
"""

from doodlecam.errors import DoodleError


class MotionError(DoodleError):
    """A motion design that cannot be built: bad conditions, laws or limits."""
