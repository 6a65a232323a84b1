"""Shared pytest set-up for the cablebot suite.

The ``vcan`` marker: a test marked ``@pytest.mark.vcan`` needs a real SocketCAN ``vcan0``
interface.  ``make test-vcan`` (tools/vcan_vm.py) runs those tests natively when the kernel has
vcan, else inside a small virtme-ng VM.  When such a test is selected but ``vcan0`` is missing it
is skipped with the reason, and under CI (``CI=true``) that skip becomes a failure, because CI
must prove the real-bus tests ran.

Fixtures for vcan tests:

* ``vcan_channel``: the interface name (``vcan0``, or ``$CABLEBOT_VCAN_CHANNEL``).
* ``vcan_bus``: a python-can socketcan bus on that interface, shut down after the test.
* ``vcan_bus_factory``: call it (with python-can keyword arguments) to open more buses; all are
  shut down after the test.
* ``under_vm`` / ``slow_factor``: ``True`` / a multiplier (> 1) when running under the emulated VM,
  where Python is several times slower: scale deadlines with it, never sleep with it.
* ``vcan_report``: append a line to it and it is printed in pytest's terminal summary (used for
  measured figures such as round-trip times).

The guest of the VM sets ``CABLEBOT_UNDER_VM=1``; subprocesses started by tests inherit it.
"""

from __future__ import annotations

import math
import os
import socket
from collections.abc import Callable, Iterator
from typing import Any

import pytest

VCAN_CHANNEL = os.environ.get("CABLEBOT_VCAN_CHANNEL", "vcan0")
# Measured: Python under the TCG-emulated VM runs about 3-6 times slower than on the host.
_DEFAULT_VM_SLOW_FACTOR = 8.0

_vcan_report_lines: list[str] = []


def running_under_ci() -> bool:
    """Return True when the CI convention ``CI=true`` is set in the environment."""
    return os.environ.get("CI", "").strip().lower() in ("true", "1", "yes")


def running_under_vm() -> bool:
    """Return True inside the virtme-ng test VM (``CABLEBOT_UNDER_VM=1``, set by the guest)."""
    return os.environ.get("CABLEBOT_UNDER_VM", "") == "1"


def slow_factor_value() -> float:
    """Return the deadline multiplier: ``$CABLEBOT_SLOW_FACTOR``, else 8 in the VM, else 1.

    Raises nothing: an unparsable or non-positive override falls back to the default.
    """
    default = _DEFAULT_VM_SLOW_FACTOR if running_under_vm() else 1.0
    raw = os.environ.get("CABLEBOT_SLOW_FACTOR", "")
    try:
        value = float(raw)
    except ValueError:
        return default
    return value if math.isfinite(value) and value > 0 else default


def vcan_status(channel: str = VCAN_CHANNEL) -> tuple[bool, str]:
    """Say whether a raw CAN socket can be bound to ``channel``.

    Returns ``(True, description)`` when it can, else ``(False, reason)``; raises nothing.
    """
    if not hasattr(socket, "AF_CAN"):
        return False, "this Python has no socket.AF_CAN (not Linux?)"
    try:
        sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    except OSError as exc:
        return False, f"the kernel has no SocketCAN (AF_CAN socket failed: {exc})"
    try:
        sock.bind((channel,))
    except OSError as exc:
        return False, f"cannot bind a CAN socket to {channel!r} ({exc})"
    finally:
        sock.close()
    return True, f"{channel} is up"


_VCAN_STATUS: tuple[bool, str] | None = None


def _cached_vcan_status() -> tuple[bool, str]:
    global _VCAN_STATUS
    if _VCAN_STATUS is None:
        _VCAN_STATUS = vcan_status()
    return _VCAN_STATUS


def pytest_report_header(config: pytest.Config) -> str:
    """Print in pytest's header whether vcan is usable and whether we run in the VM."""
    ok, reason = _cached_vcan_status()
    where = "inside the virtme-ng VM" if running_under_vm() else "natively"
    return (
        f"cablebot: {where}; {VCAN_CHANNEL}: {'available' if ok else 'MISSING'} ({reason}); "
        f"CI={'true' if running_under_ci() else 'no'}; slow_factor={slow_factor_value():g}"
    )


def pytest_runtest_setup(item: pytest.Item) -> None:
    """Skip a ``vcan`` test when vcan0 is missing, or fail it under CI."""
    if item.get_closest_marker("vcan") is None:
        return
    ok, reason = _cached_vcan_status()
    if ok:
        return
    message = (
        f"vcan test needs SocketCAN {VCAN_CHANNEL}: {reason}. Run `make test-vcan` "
        "(it uses the VM when the kernel has no vcan) or `sudo modprobe vcan && "
        f"sudo ip link add dev {VCAN_CHANNEL} type vcan && sudo ip link set up {VCAN_CHANNEL}`."
    )
    if running_under_ci():
        pytest.fail("CI=true forbids skipping: " + message, pytrace=False)
    pytest.skip(message)


def pytest_terminal_summary(terminalreporter: Any) -> None:
    """Print the figures that vcan tests recorded through the ``vcan_report`` fixture."""
    if _vcan_report_lines:
        terminalreporter.section("vcan measurements")
        for line in _vcan_report_lines:
            terminalreporter.write_line(line)


@pytest.fixture
def under_vm() -> bool:
    """True when the test runs inside the emulated virtme-ng VM."""
    return running_under_vm()


@pytest.fixture
def slow_factor() -> float:
    """Multiplier for deadlines (not for sleeps): > 1 under the emulated VM."""
    return slow_factor_value()


@pytest.fixture
def vcan_report() -> list[str]:
    """A list whose lines are printed in the terminal summary at the end of the run."""
    return _vcan_report_lines


@pytest.fixture
def vcan_channel() -> str:
    """The SocketCAN interface used by vcan tests."""
    return VCAN_CHANNEL


@pytest.fixture
def vcan_bus_factory(vcan_channel: str) -> Iterator[Callable[..., Any]]:
    """Yield a function opening ``can.Bus(interface="socketcan", channel=vcan0, **kwargs)``.

    Every bus it opened is shut down after the test. Opening raises ``can.CanError`` / ``OSError``
    when the interface is unusable.
    """
    import can

    buses: list[can.BusABC] = []

    def open_bus(**kwargs: Any) -> can.BusABC:
        bus = can.Bus(interface="socketcan", channel=vcan_channel, **kwargs)
        buses.append(bus)
        return bus

    yield open_bus
    for bus in buses:
        bus.shutdown()


@pytest.fixture
def vcan_bus(vcan_bus_factory: Callable[..., Any]) -> Any:
    """A python-can socketcan bus on vcan0 (shut down after the test)."""
    return vcan_bus_factory()
