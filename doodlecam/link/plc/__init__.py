"""The DoodleBot PLC link: the packet file, the UDP wire protocol, the sender and a simulator.
"""
