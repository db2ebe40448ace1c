"""Planning: the time-optimal feed profile along each spline (constraint rows, the exact
reachability pass, the LP/QP back-ends), the velocity samples the PLC executes, how far
its ramps stray between samples, and the pen-up travel moves.

``plan_stroke`` and friends live in ``doodlecam.plan.planner``.
"""
