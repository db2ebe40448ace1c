"""doodlecam: pictures to time-optimal pen-plotter jobs.

Data flows one way through small stages (README.md, "Layout"):
trace -> layout -> fit -> order -> plan -> sample -> post.
This package import stays light on purpose: heavy libraries are imported by
the stage that needs them, so ``doodlecam --help`` answers fast.
"""

# Bumped whenever outputs change for the same input and options: batch manifests
# hash it, so a re-run redoes what an older version wrote.
__version__ = "0.2.0"
