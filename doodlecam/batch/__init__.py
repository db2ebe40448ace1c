"""Batch conversion of a folder of pictures: parallel, incremental, resumable (``doodlecam batch``).
"""
