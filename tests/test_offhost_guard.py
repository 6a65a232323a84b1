"""The off-host traffic guard (tools/offhost_guard.py) and the host-only udp_multicast default.

The guard wraps `make test` and `make bench`. Here it is shown to fail on a bus that would leave
the host: inside a network namespace made for the test, with a veth pair as its only
non-loopback link (so nothing reaches a real network), a udp_multicast bus opened with a TTL of 1
is caught, and the same bus through `drivers.bus.open_bus`'s default is not.
"""

from __future__ import annotations

import os
import shutil
import socket
import struct
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.conftest import running_under_ci

ROOT = Path(__file__).resolve().parent.parent
GUARD = ROOT / "tools" / "offhost_guard.py"

sys.path.insert(0, str(ROOT / "tools"))
import offhost_guard  # noqa: E402


def _udp_frame_v4(dst: str, port: int) -> bytes:
    eth = b"\x01\x00\x5e\x4a\x00\x01" + b"\x02" * 6 + b"\x08\x00"
    ip = bytes([0x45, 0, 0, 32, 0, 0, 0, 0, 1, 17, 0, 0]) + socket.inet_aton("10.0.0.1")
    ip += socket.inet_aton(dst)
    return eth + ip + struct.pack("!HHHH", 40000, port, 12, 0) + b"abcd"


def test_udp_destination_parses_ipv4_and_ipv6_and_ignores_others() -> None:
    assert offhost_guard.udp_destination(_udp_frame_v4("239.74.1.2", 43113)) == (
        "239.74.1.2",
        43113,
    )
    tcp = bytearray(_udp_frame_v4("239.74.1.2", 43113))
    tcp[23] = 6
    assert offhost_guard.udp_destination(bytes(tcp)) is None
    v6 = (
        b"\x33\x33\x00\x00\x00\x01"
        + b"\x02" * 6
        + b"\x86\xdd"
        + bytes([0x60, 0, 0, 0, 0, 12, 17, 0])
        + socket.inet_pton(socket.AF_INET6, "fe80::1")
        + socket.inet_pton(socket.AF_INET6, "ff15::7")
        + struct.pack("!HHHH", 40000, 5000, 12, 0)
        + b"abcd"
    )
    assert offhost_guard.udp_destination(v6) == ("ff15::7", 5000)
    assert offhost_guard.udp_destination(b"\x00" * 13) is None
    assert offhost_guard.udp_destination(_udp_frame_v4("239.74.1.2", 43113)[:30]) is None


_SENDER = """
import can, sys
from drivers.bus import open_bus
hop = {hop!r}
opts = {{}} if hop is None else {{"hop_limit": hop}}
bus = open_bus("udp_multicast", "239.74.77.77", port=47077, **opts)
for i in range(20):
    bus.send(can.Message(arbitration_id=0x0C, data=bytes(8), is_extended_id=False))
bus.shutdown()
"""


def _in_namespace(hop_limit: int | None) -> subprocess.CompletedProcess[str]:
    setup = textwrap.dedent(
        """
        set -e
        ip link set lo up
        ip link add cbv0 type veth peer name cbv1
        ip addr add 10.213.0.1/24 dev cbv0
        ip link set cbv0 up
        ip link set cbv1 up
        ip route add default via 10.213.0.2 dev cbv0
        """
    )
    guard = [sys.executable, str(GUARD), "--", sys.executable, "-c", _SENDER.format(hop=hop_limit)]
    script = setup + " ".join(f"'{a}'" for a in guard) + "\n"
    return subprocess.run(
        ["unshare", "-n", "bash", "-c", script],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )


def _need_namespaces() -> None:
    missing = [tool for tool in ("unshare", "ip") if shutil.which(tool) is None]
    reason = ""
    if os.geteuid() != 0:
        reason = "needs root to make a network namespace"
    elif missing:
        reason = f"needs {', '.join(missing)}"
    if reason:
        if running_under_ci():
            pytest.fail(f"CI=true forbids skipping the off-host guard test: {reason}")
        pytest.skip(reason)


def test_guard_fails_a_ttl_1_bus_and_passes_the_default() -> None:
    _need_namespaces()
    leaking = _in_namespace(1)
    assert leaking.returncode == offhost_guard.GUARD_FAILED, leaking.stdout + leaking.stderr
    assert "FAILED: traffic left this host" in leaking.stdout
    assert "to [239.74.77.77]:47077 via cbv0" in leaking.stdout
    host_only = _in_namespace(None)
    assert host_only.returncode == 0, host_only.stdout + host_only.stderr
    assert "outgoing UDP packets 0 (budget 0)" in host_only.stdout
