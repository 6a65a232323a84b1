#!/usr/bin/env python3
"""Run a command and fail if it sent UDP traffic off this host.

    python tools/offhost_guard.py [--budget N] -- COMMAND [ARG ...]

cablebot's tests, benchmark and simulator carry CAN frames between processes over python-can's
udp_multicast interface and talk Zenoh over TCP. All of it must stay on this machine. This guard
watches every network interface except loopback while COMMAND runs, and exits non-zero when
COMMAND succeeded but traffic left the host:

* **Packet watch** (root, Linux): a raw packet socket (AF_PACKET) on each non-loopback interface
  counts the *outgoing UDP* packets, which is what a udp_multicast CAN bus or Zenoh's multicast
  scouting send. Name lookups, time and address configuration (UDP ports 53, 67, 68, 123) are
  background and not counted; neither are IGMP/MLD membership reports (not UDP) nor the TCP of
  other programs on the machine (a package download beside the tests). More than `--budget`
  counted packets (default 0) fails the run, and the report names the destinations.
* **Counter check** (no raw sockets): the transmitted-packet counters of `/proc/net/dev` for the
  non-loopback interfaces, before and after; a rise above `--counter-budget` (default 200, for
  background traffic) fails the run.

Both figures are printed in one line at the end either way. The exit status is COMMAND's when it
failed, 3 when COMMAND passed but the guard did not, else 0.
"""

from __future__ import annotations

import argparse
import collections
import os
import select
import socket
import struct
import subprocess
import sys
import threading
from pathlib import Path

_ETH_P_ALL = 0x0003
_PACKET_OUTGOING = 4
_BACKGROUND_UDP_PORTS = frozenset({53, 67, 68, 123, 546, 547})
GUARD_FAILED = 3


def tx_packets() -> dict[str, int]:
    """Return the transmitted-packet counter of every non-loopback interface (/proc/net/dev).

    Raises OSError if /proc/net/dev cannot be read.
    """
    counters: dict[str, int] = {}
    for line in Path("/proc/net/dev").read_text().splitlines()[2:]:
        name, _, fields = line.partition(":")
        name = name.strip()
        values = fields.split()
        if name == "lo" or len(values) < 10:
            continue
        counters[name] = int(values[9])
    return counters


def udp_destination(frame: bytes) -> tuple[str, int] | None:
    """Return (address, port) of an Ethernet frame carrying UDP over IPv4/IPv6, else None.

    Pure; raises nothing (a short or malformed frame gives None).
    """
    if len(frame) < 14:
        return None
    ethertype = struct.unpack_from("!H", frame, 12)[0]
    if ethertype == 0x0800 and len(frame) >= 34:
        ihl = (frame[14] & 0x0F) * 4
        if frame[23] != 17 or len(frame) < 14 + ihl + 4:
            return None
        port = struct.unpack_from("!H", frame, 14 + ihl + 2)[0]
        return socket.inet_ntop(socket.AF_INET, frame[30:34]), port
    if ethertype == 0x86DD and len(frame) >= 58:
        if frame[20] != 17:
            return None
        port = struct.unpack_from("!H", frame, 54 + 2)[0]
        return socket.inet_ntop(socket.AF_INET6, frame[38:54]), port
    return None


class PacketWatch:
    """Counts outgoing UDP packets on the given interfaces in a background thread."""

    def __init__(self, interfaces: list[str]) -> None:
        """Open one raw packet socket per interface. Raises OSError without the privilege."""
        self._socks: list[socket.socket] = []
        try:
            for name in interfaces:
                s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(_ETH_P_ALL))
                s.bind((name, 0))
                s.setblocking(False)
                self._socks.append(s)
        except OSError:
            self.close()
            raise
        self.destinations: collections.Counter[tuple[str, str, int]] = collections.Counter()
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name="offhost-watch", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        by_fd = {s.fileno(): s for s in self._socks}
        fds = [*by_fd, self._stop_r]
        while True:
            ready, _, _ = select.select(fds, [], [])
            for fd in ready:
                if fd == self._stop_r:
                    return
                self._drain(by_fd[fd])

    def _drain(self, s: socket.socket) -> None:
        while True:
            try:
                frame, addr = s.recvfrom(65535)
            except OSError:  # nothing queued (EAGAIN), or the interface is down (ENETDOWN)
                return
            if addr[2] != _PACKET_OUTGOING:
                continue
            dest = udp_destination(frame)
            if dest is not None and dest[1] not in _BACKGROUND_UDP_PORTS:
                self.destinations[(addr[0], *dest)] += 1

    @property
    def count(self) -> int:
        """Outgoing UDP packets counted so far."""
        return sum(self.destinations.values())

    def stop(self) -> None:
        """Drain what is queued, stop the thread and close the sockets."""
        os.write(self._stop_w, b"x")
        self._thread.join(timeout=5.0)
        for s in self._socks:
            self._drain(s)
        self.close()
        os.close(self._stop_r)
        os.close(self._stop_w)

    def close(self) -> None:
        """Close the packet sockets."""
        for s in self._socks:
            s.close()
        self._socks = []


def main(argv: list[str] | None = None) -> int:
    """Run the command under the guard; return the exit status described in the module doc."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--budget", type=int, default=int(os.environ.get("CABLEBOT_OFFHOST_BUDGET", 0)))
    p.add_argument("--counter-budget", type=int, default=200)
    p.add_argument("command", nargs=argparse.REMAINDER)
    args = p.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        p.error("no command given")

    before = tx_packets()
    watch: PacketWatch | None
    try:
        watch = PacketWatch(sorted(before))
    except (OSError, AttributeError) as exc:
        watch = None
        why = f"{type(exc).__name__}: {exc}"
    rc = subprocess.call(command)
    after = tx_packets()
    rise = sum(after.get(name, 0) - n for name, n in before.items())
    per_if = ", ".join(f"{name} +{after.get(name, 0) - n}" for name, n in sorted(before.items()))
    line = f"offhost guard: non-loopback transmit counters {per_if or '(no interfaces)'}"
    failed = False
    if watch is not None:
        watch.stop()
        line += f"; outgoing UDP packets {watch.count} (budget {args.budget})"
        failed = watch.count > args.budget
        if watch.destinations:
            top = ", ".join(
                f"{n} to [{addr}]:{port} via {ifname}"
                for (ifname, addr, port), n in watch.destinations.most_common(5)
            )
            line += f": {top}"
    else:
        line += f" (no packet watch: {why}; counter budget {args.counter_budget})"
        failed = rise > args.counter_budget
    print(line + ("  FAILED: traffic left this host" if failed else "  ok"), flush=True)
    if rc != 0:
        return rc
    return GUARD_FAILED if failed else 0


if __name__ == "__main__":
    sys.exit(main())
