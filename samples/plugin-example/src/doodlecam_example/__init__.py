"""Example doodlecam plugin package (see hpgl.py)."""
