"""systemd's watchdog: WATCHDOG=1 only when systemd asked for one, at half its period."""

from __future__ import annotations

import os
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from controller.service.daemon import Notifier
from controller.service.runner import Runner

PERIOD_S = 0.002
RUN_S = 5.0


class StepClock:
    """A clock that only sleeping and the step move."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s

    def sleep(self, dt_s: float) -> None:
        self.now_s += max(dt_s, 0.0)


@pytest.fixture
def notify_socket(tmp_path: Path) -> Iterator[tuple[str, socket.socket]]:
    """A real AF_UNIX datagram socket, as systemd's NOTIFY_SOCKET is."""
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.setblocking(False)
    yield path, sock
    sock.close()


def received(sock: socket.socket) -> list[str]:
    got: list[str] = []
    while True:
        try:
            got.append(sock.recv(4096).decode())
        except BlockingIOError:
            return got


def run_like_the_daemon(env: dict[str, str]) -> None:
    """Run the loop for RUN_S simulated seconds with the daemon's watchdog wiring."""
    notifier = Notifier(env)
    clk = StepClock()
    stop = threading.Event()

    def step(now_s: float) -> None:
        clk.now_s += 0.0001
        if now_s >= RUN_S:
            stop.set()

    try:
        Runner(step, PERIOD_S, clock=clk, sleep=clk.sleep, spin_s=0.0).run(
            stop,
            on_watchdog=lambda: notifier.notify("WATCHDOG=1"),
            watchdog_period_s=notifier.watchdog_period_s,
        )
    finally:
        notifier.close()


def test_no_watchdog_pings_when_systemd_did_not_ask_for_a_watchdog(
    notify_socket: tuple[str, socket.socket],
) -> None:
    # Type=notify without WatchdogSec: NOTIFY_SOCKET set, no WATCHDOG_USEC.
    path, sock = notify_socket
    run_like_the_daemon({"NOTIFY_SOCKET": path})
    assert received(sock) == []


@pytest.mark.parametrize(
    "extra",
    [
        {"WATCHDOG_USEC": "1000000", "WATCHDOG_PID": "1"},  # meant for another process
        {"WATCHDOG_USEC": "0"},
        {"WATCHDOG_USEC": "soon"},
    ],
)
def test_no_watchdog_pings_for_a_watchdog_meant_for_another_process_or_off(
    notify_socket: tuple[str, socket.socket], extra: dict[str, str]
) -> None:
    path, sock = notify_socket
    run_like_the_daemon({"NOTIFY_SOCKET": path, **extra})
    assert received(sock) == []


@pytest.mark.parametrize("pid", [None, "own"])
def test_watchdog_pings_at_half_the_period_systemd_asked_for(
    notify_socket: tuple[str, socket.socket], pid: str | None
) -> None:
    path, sock = notify_socket
    env = {"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "1000000"}  # WatchdogSec=1
    if pid is not None:
        env["WATCHDOG_PID"] = str(os.getpid())
    run_like_the_daemon(env)
    got = received(sock)
    assert set(got) == {"WATCHDOG=1"}
    # every 0.5 s over 5 s: 10 (one fewer if the last falls just after the end)
    assert 9 <= len(got) <= 10, len(got)
