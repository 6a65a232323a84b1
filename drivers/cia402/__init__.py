"""CANopen servo drives (CiA 402) in cyclic synchronous position mode.

`CiA402Reels` (driver.py) is the `ReelDriver`; `SimCiA402Bank` / `SimCiA402Drive` (sim.py)
simulate the drives; `sdo_config` holds the start-up configuration by SDO, `profile` the state
machine and EMCY names, `busload` the bits of a CAN frame. `cia402.eds` is the object
dictionary shipped with cablebot.
"""

from drivers.cia402.driver import EDS_PATH, CiA402Reels, DriveStatus
from drivers.cia402.sdo_config import ConfigureError

__all__ = ["EDS_PATH", "CiA402Reels", "ConfigureError", "DriveStatus"]
