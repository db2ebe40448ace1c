"""doodlecam: pictures to time-optimal pen-plotter jobs.

Data flows one way through small stages (see DESIGN.md):
trace -> layout -> fit -> order -> plan -> sample -> post.
This package import stays light on purpose: heavy libraries are imported by
the stage that needs them, so ``doodlecam --help`` answers fast.
"""

__version__ = "0.1.0"
