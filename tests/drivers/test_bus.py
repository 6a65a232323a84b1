"""drivers.bus.open_bus: host-only udp_multicast, and errors that say what to do."""

from __future__ import annotations

import errno
import random
from pathlib import Path
from typing import Any

import can
import pytest

from drivers import bus as bus_mod
from drivers.bus import BusOpenError, open_bus


def _raising(exc: BaseException) -> Any:
    def fake_bus(**kwargs: Any) -> can.BusABC:
        raise exc

    return fake_bus


def test_no_socketcan_in_the_kernel_names_the_way_out(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(
        bus_mod.can,
        "Bus",
        _raising(OSError(errno.EAFNOSUPPORT, "Address family not supported by protocol")),
    )
    with pytest.raises(BusOpenError) as info:
        open_bus("socketcan", "can0")
    text = str(info.value)
    assert "interface='socketcan' channel='can0'" in text
    assert "no SocketCAN (AF_CAN)" in text and "udp_multicast" in text


def test_missing_can_interface_says_how_to_bring_it_up(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bus_mod.can, "Bus", _raising(OSError(errno.ENODEV, "No such device")))
    with pytest.raises(BusOpenError, match=r"sudo ip link set can1 up type can bitrate"):
        open_bus("socketcan", "can1")


def test_unknown_interface_lists_the_known_ones() -> None:
    with pytest.raises(BusOpenError) as info:
        open_bus("no_such_interface", "x")
    assert "socketcan" in str(info.value) and "udp_multicast" in str(info.value)


def test_udp_multicast_hop_limit_default_and_explicit() -> None:
    bus = open_bus("udp_multicast", "239.74.250.252", port=47003)
    try:
        assert bus._multicast.hop_limit == 0
    finally:
        bus.shutdown()
    bus = open_bus("udp_multicast", "239.74.250.253", port=47004, hop_limit=3)
    try:
        assert bus._multicast.hop_limit == 3
    finally:
        bus.shutdown()


def test_a_udp_multicast_receiver_that_does_not_run_for_a_while_keeps_its_frames() -> None:
    # A simulated drive or the controller starved on a busy host: the kernel keeps what
    # arrives meanwhile only as far as the socket's receive buffer goes, then drops the newest
    # frames (the last set-points of a stop among them). 2,000 frames is about a second of a
    # robot's traffic; the default buffer keeps a few hundred.
    try:
        rmem_max = int(Path("/proc/sys/net/core/rmem_max").read_text())
    except OSError:
        pytest.skip("no /proc/sys/net/core/rmem_max")
    if rmem_max < 4 * 1024 * 1024:
        pytest.skip(f"net.core.rmem_max is {rmem_max}: the kernel caps the buffer below that")
    group = f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}"
    port = random.randint(40000, 49000)
    receiver = open_bus("udp_multicast", group, port=port)
    sender = open_bus("udp_multicast", group, port=port)
    try:
        n = 2000
        for i in range(n):
            sender.send(
                can.Message(arbitration_id=0x0C, data=i.to_bytes(8, "little"), is_extended_id=False)
            )
        got = []
        while (msg := receiver.recv(0.5)) is not None:
            got.append(int.from_bytes(msg.data, "little"))
        assert got[-1] == n - 1 and len(got) == n, (len(got), got[-3:])
    finally:
        receiver.shutdown()
        sender.shutdown()
