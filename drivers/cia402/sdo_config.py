"""The CiA 402 drives' start-up configuration by SDO (`drivers.cia402.driver` describes it):
the steps for one drive, the SDO and PDO helpers, and each PDO's precompiled struct.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Sequence

import canopen
from canopen.objectdictionary import datatypes
from canopen.pdo import PdoMap
from canopen.pdo.base import PDO_NOT_VALID
from canopen.sdo.base import SdoVariable
from canopen.sdo.exceptions import SdoAbortedError, SdoError

from drivers.base import DriverError
from drivers.cia402.profile import CYCLIC_SYNCHRONOUS_POSITION

SYNC_COB_ID = 0x80
RPDO1_OBJECTS = (0x6040, 0x607A)
"""RPDO1: controlword, target position."""
RPDO2_OBJECTS = (0x60B1,)
"""RPDO2: velocity offset (the velocity feed-forward)."""
_MODE_DISPLAY_WAIT_S = 0.2

_FORMATS = {
    datatypes.INTEGER8: "b",
    datatypes.UNSIGNED8: "B",
    datatypes.INTEGER16: "h",
    datatypes.UNSIGNED16: "H",
    datatypes.INTEGER32: "i",
    datatypes.UNSIGNED32: "I",
}


class ConfigureError(DriverError):
    """A drive could not be configured; the message names the node, the step and why
    (SDO timeout, SDO abort with its code, an object missing from the EDS, a refused mode)."""


def pdo_struct(pdo: PdoMap) -> struct.Struct:
    """The little-endian struct of a configured PDO (byte-aligned integer objects only)."""
    fmt = "<"
    offset = 0
    for var in pdo.map:
        code = _FORMATS.get(var.od.data_type or 0)
        if code is None or var.length != 8 * struct.calcsize(code) or var.offset != offset:
            raise ConfigureError(
                f"0x{var.index:04X} ({var.name}) is not a byte-aligned 8/16/32-bit integer "
                f"in {pdo.name}"
            )
        fmt += code
        offset += var.length
    return struct.Struct(fmt)


def configure_node(
    node: canopen.RemoteNode,
    n: int,
    *,
    heartbeat_ms: int,
    interp: tuple[int, int],
    velocity_offset: bool,
    torque: bool,
) -> tuple[PdoMap, PdoMap | None, PdoMap]:
    """Configure drive `n` by SDO as `drivers.cia402.driver` describes and start it (NMT
    OPERATIONAL): its RPDO1, RPDO2 (None with no `velocity_offset`) and TPDO1. Raises
    ConfigureError naming the node, the step and why."""
    step = "NMT PRE-OPERATIONAL"
    try:
        node.nmt.state = "PRE-OPERATIONAL"
        step = "0x1005 COB-ID SYNC"
        write(node.sdo[0x1005], SYNC_COB_ID)
        step = "0x1017 heartbeat producer time"
        write(node.sdo[0x1017], heartbeat_ms)
        step = "0x6060 modes of operation"
        write(node.sdo[0x6060], CYCLIC_SYNCHRONOUS_POSITION)
        step = "0x60C2 interpolation time period"
        value, index = interp
        write(node.sdo[0x60C2][1], value)
        write(node.sdo[0x60C2][2], index)
        step = "RPDO1"
        rpdo1 = set_pdo(node.rpdo[1], 0x200 + n, RPDO1_OBJECTS, rtr=True)
        step = "RPDO2"
        rpdo2 = None
        if velocity_offset:
            rpdo2 = set_pdo(node.rpdo[2], 0x300 + n, RPDO2_OBJECTS, rtr=True)
        else:
            disable_pdo(node.rpdo[2])
        for i in (3, 4):
            step = f"RPDO{i}"
            disable_pdo(node.rpdo[i])
        step = "TPDO1"
        tpdo1 = set_pdo(node.tpdo[1], 0x180 + n, tpdo1_objects(torque), rtr=False)
        for i in (2, 3, 4):
            step = f"TPDO{i}"
            disable_pdo(node.tpdo[i])
        step = "0x6061 modes of operation display"
        check_mode(node)
        step = "NMT OPERATIONAL"
        node.nmt.state = "OPERATIONAL"
    except (SdoError, DriverError, KeyError) as exc:
        raise ConfigureError(f"node {n}: {step}: {type(exc).__name__}: {exc}") from exc
    return rpdo1, rpdo2, tpdo1


def tpdo1_objects(torque: bool) -> tuple[int, ...]:
    """TPDO1: statusword, position actual, and torque actual with `torque`."""
    return (0x6041, 0x6064, 0x6077) if torque else (0x6041, 0x6064)


def local_mapping(
    node: canopen.RemoteNode, n: int, *, velocity_offset: bool, torque: bool
) -> tuple[PdoMap, PdoMap | None, PdoMap]:
    """The RPDO1, RPDO2 (None with no `velocity_offset`) and TPDO1 that `configure_node` writes
    to drive `n`, mapped in `node`'s local copy only (nothing is sent): for drives known to hold
    that mapping already (the benchmark). Raises ConfigureError if the dictionary lacks an
    object."""
    rpdo1 = map_pdo(node.rpdo[1], 0x200 + n, RPDO1_OBJECTS, rtr=True)
    rpdo2 = map_pdo(node.rpdo[2], 0x300 + n, RPDO2_OBJECTS, rtr=True) if velocity_offset else None
    tpdo1 = map_pdo(node.tpdo[1], 0x180 + n, tpdo1_objects(torque), rtr=False)
    return rpdo1, rpdo2, tpdo1


def write(var: object, value: int) -> None:
    """SDO-write `value`; an object that refuses but already holds it is accepted."""
    if not isinstance(var, SdoVariable):
        raise ConfigureError(f"{var!r} is not a single object in the drive's dictionary")
    try:
        var.raw = value
    except SdoAbortedError:
        try:
            held = var.raw
        except SdoError:
            held = None
        if held != value:
            raise


def disable_pdo(pdo: PdoMap) -> int:
    """Mark a PDO invalid (COB-ID bit 31), keeping its COB-ID; return that COB-ID."""
    cob_var = pdo.com_record[1]
    cob = int(cob_var.raw)
    if not cob & PDO_NOT_VALID:
        write(cob_var, cob | PDO_NOT_VALID)
    return cob & 0x7FF


def set_pdo(pdo: PdoMap, cob_id: int, objects: Sequence[int], *, rtr: bool) -> PdoMap:
    """Map `objects` into `pdo`, synchronous (type 1), at `cob_id`, and enable it."""
    cob_var = pdo.com_record[1]
    cob = int(cob_var.raw)
    if not cob & PDO_NOT_VALID and cob & 0x7FF != cob_id:
        # A valid PDO keeps its COB-ID: disable it under its own before moving it.
        write(cob_var, cob | PDO_NOT_VALID)
    map_pdo(pdo, cob_id, objects, rtr=rtr)
    pdo.save()
    return pdo


def map_pdo(pdo: PdoMap, cob_id: int, objects: Sequence[int], *, rtr: bool) -> PdoMap:
    """Map `objects` into the local copy of `pdo`, synchronous (type 1), at `cob_id`, enabled;
    nothing is sent. Raises ConfigureError if the dictionary lacks an object."""
    pdo.clear()
    for index in objects:
        if pdo.add_variable(index) is None:
            raise ConfigureError(f"0x{index:04X} is not in the drive's object dictionary")
    pdo.cob_id = cob_id
    pdo.trans_type = 1
    pdo.rtr_allowed = rtr
    pdo.enabled = True
    return pdo


def check_mode(node: canopen.RemoteNode) -> None:
    """Wait (bounded) until 0x6061 shows cyclic synchronous position."""
    deadline = time.monotonic() + _MODE_DISPLAY_WAIT_S
    while True:
        shown = int(node.sdo[0x6061].raw)
        if shown == CYCLIC_SYNCHRONOUS_POSITION:
            return
        if time.monotonic() >= deadline:
            raise ConfigureError(
                f"the drive shows mode {shown} after 0x6060 was set to cyclic synchronous "
                "position (8): it does not support it"
            )
        time.sleep(0.01)
