"""Open a python-can bus from configuration, for any interface python-can supports.

`open_bus("socketcan", "can0", 1_000_000)`, `open_bus("virtual", "sim")`,
`open_bus("udp_multicast", "239.74.0.1", port=43113)`, `open_bus({"interface": "pcan",
"channel": "PCAN_USBBUS1", "bitrate": 500000})`: every further keyword goes to the interface
unchanged, so new interfaces need no code here. One bus per robot, passed into the drivers.
On a SocketCAN bus the ODrive driver then reads and writes the bus's kernel socket directly
(`drivers.socketcan_fast`: batched system calls, kernel filters, no Message objects).

udp_multicast stays on this host unless told otherwise: python-can's own default multicast TTL
(`hop_limit`) is 1, which sends every CAN frame out of the default network interface onto the
local network. Here `hop_limit` defaults to 0 (delivered between processes on this host only; a
TTL of 0 never reaches a wire). A configuration that sets `hop_limit` itself, for a deliberate
bus across hosts, keeps its value. python-can offers no option to pin the outgoing interface.

A udp_multicast receiver that the OS does not run for a while (a simulated drive or the
controller on a busy host) keeps what arrives meanwhile in its socket's receive buffer; when that
is full the kernel drops the newest frames, such as the last set-points of a stop. The default
buffer (net.core.rmem_default, about 200 KiB) holds a tenth of a second of a robot's traffic:
each udp_multicast bus asks for `UDP_RCVBUF_BYTES` instead (the kernel grants at most
net.core.rmem_max).
"""

from __future__ import annotations

import errno
import socket
from collections.abc import Mapping
from typing import Any

import can

from drivers.base import DriverError

# Interfaces whose bit rate is set outside python-can (or that have none): a configured bitrate is
# not passed to them, so one config file works on a real bus and on these.
_NO_BITRATE = frozenset({"virtual", "udp_multicast", "socketcan"})

#: The multicast TTL cablebot gives a udp_multicast bus whose configuration does not set one:
#: 0 keeps every frame on this host.
HOST_ONLY_HOP_LIMIT = 0

#: The receive buffer a udp_multicast bus asks for: seconds of a robot's traffic (the kernel
#: caps it at net.core.rmem_max).
UDP_RCVBUF_BYTES = 4 * 1024 * 1024


class BusOpenError(DriverError):
    """The bus could not be opened; the message names the interface and channel and why."""


def open_bus(
    interface: str | Mapping[str, Any],
    channel: str | int | None = None,
    bitrate: int | None = None,
    **options: Any,
) -> can.BusABC:
    """Open and return a python-can bus.

    `interface` is a python-can interface name ("socketcan", "virtual", "udp_multicast",
    "pcan", "slcan", ...), or a mapping with keys "interface", "channel", "bitrate" and any
    further interface keyword (explicit arguments override the mapping). `bitrate` is passed
    only to interfaces that set it themselves (not socketcan, whose bit rate belongs to
    `ip link`, nor virtual/udp_multicast). Raises BusOpenError (with interface and channel in
    the message) if the interface is unknown or the bus cannot be opened, and ValueError on a
    malformed configuration. A udp_multicast bus gets `hop_limit=0` (host-only) unless
    `hop_limit` is given.
    """
    if isinstance(interface, Mapping):
        cfg = dict(interface)
        name = cfg.pop("interface", None)
        channel = cfg.pop("channel", None) if channel is None else channel
        cfg_bitrate = cfg.pop("bitrate", None)
        bitrate = cfg_bitrate if bitrate is None else bitrate
        options = {**cfg, **options}
    else:
        name = interface
    if not isinstance(name, str) or not name:
        raise ValueError(f"bus configuration needs an interface name, got {name!r}")
    if bitrate is not None and (not isinstance(bitrate, int) or bitrate <= 0):
        raise ValueError(f"bitrate must be a positive integer, got {bitrate!r}")
    kwargs: dict[str, Any] = dict(options)
    if bitrate is not None and name not in _NO_BITRATE:
        kwargs["bitrate"] = bitrate
    if name == "udp_multicast":
        kwargs.setdefault("hop_limit", HOST_ONLY_HOP_LIMIT)
    try:
        bus = can.Bus(interface=name, channel=channel, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError, TypeError, NotImplementedError) as exc:
        hint = _hint(name, channel, exc)
        raise BusOpenError(
            f"cannot open CAN bus interface={name!r} channel={channel!r}: "
            f"{type(exc).__name__}: {exc}" + (f". {hint}" if hint else "")
        ) from exc
    if name == "udp_multicast":
        enlarge_receive_buffer(bus)
    return bus


def frame_message(arb_id: int, data: bytes, is_remote: bool) -> can.Message:
    """The python-can `Message` of a standard-id frame (id, data, is_remote), as the drivers'
    and simulators' encoders give it: a remote frame asks for 8 bytes. Raises nothing for a
    frame they make (python-can raises ValueError on more than 8 data bytes)."""
    return can.Message(
        arbitration_id=arb_id,
        data=data,
        is_extended_id=False,
        is_remote_frame=is_remote,
        dlc=8 if is_remote else len(data),
    )


def echoes_own_frames(bus: object) -> bool:
    """Whether `bus` hands this host's own frames back to it: python-can's udp_multicast does
    (every socket of the group hears every datagram), and so does a bus opened with
    `receive_own_messages`; SocketCAN (own frames off) and virtual do not. Raises nothing."""
    return (
        type(bus).__name__ == "UdpMulticastBus"
        or getattr(bus, "receive_own_messages", False) is True
    )


def enlarge_receive_buffer(bus: can.BusABC, size_bytes: int = UDP_RCVBUF_BYTES) -> int:
    """Ask for a `size_bytes` receive buffer on a udp_multicast bus's socket (see the module
    docstring); return the size the kernel granted (as getsockopt reports it), 0 if the bus
    has no such socket or the request failed. Raises nothing."""
    sock = getattr(getattr(bus, "_multicast", None), "_socket", None)
    if not isinstance(sock, socket.socket):
        return 0
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size_bytes)
        return int(sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF))
    except OSError:
        return 0


def _hint(name: str, channel: object, exc: BaseException) -> str:
    """What a person can do about a bus that would not open (empty when nothing useful)."""
    errno_ = getattr(exc, "errno", None)
    cause = exc.__cause__ or exc.__context__
    if errno_ is None and cause is not None:
        errno_ = getattr(cause, "errno", None)
    if name == "socketcan":
        if errno_ == errno.EAFNOSUPPORT:
            return (
                "This kernel has no SocketCAN (AF_CAN). On a machine with a CAN adapter load the "
                "driver (`sudo modprobe can_raw`); without CAN hardware run the simulated robot "
                '(`cablebot run` without --config) or set [bus] interface = "udp_multicast"'
            )
        if errno_ == errno.ENODEV:
            return (
                f"No interface {channel!r}: bring it up with "
                f"`sudo ip link set {channel} up type can bitrate 1000000` "
                f"(or `sudo ip link add dev {channel} type vcan && sudo ip link set up {channel}` "
                "for a virtual one)"
            )
        if errno_ == errno.ENETDOWN:
            return f"{channel!r} is down: `sudo ip link set {channel} up type can bitrate 1000000`"
    if isinstance(exc, ImportError | NotImplementedError) or "unknown interface" in str(exc):
        return f"python-can's interfaces are: {', '.join(sorted(can.interfaces.VALID_INTERFACES))}"
    return ""
