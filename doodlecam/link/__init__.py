"""The machine links: the PLC over UDP (``link.plc``) and GRBL over serial (``link.grbl``).
"""
