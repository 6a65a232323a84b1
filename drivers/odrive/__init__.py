"""ODrive drives over CANSimple: the codec, the driver and a simulated node."""
