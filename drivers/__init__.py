"""cablebot drivers: CAN bus, ODrive CANSimple codec and driver, reel model, simulated node."""
