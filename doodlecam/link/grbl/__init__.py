"""The GRBL link: the protocol's tables and parsers, the serial port, the streamer, an emulator
on a pseudo-terminal and a model of GRBL's planner for job times.
"""
