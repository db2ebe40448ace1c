"""Tracing support: picture loading for the image tracers, and the layout of a drawing into the
work area. The tracers themselves are plugins (``doodlecam.plugins``).
"""
