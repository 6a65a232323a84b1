"""Stopping and starting safely: braking on SIGTERM, the drives' watchdog after kill -9, READY.

The process tests run the simulated ODrives (`cablebot sim` or `python -m drivers.odrive.sim`),
the daemon (`cablebot run`) and this test as separate processes on a loopback udp_multicast bus
(hop_limit 0); the test also listens on the bus, so what the drives were sent and what they did
is measured on the wire, not taken from the daemon's word.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import logging
import math
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import pytest

from controller.core import kinematics
from controller.core.commands import Arm, CommandRefused, Move
from controller.core.motion import BRAKE_ACCEL_SHARE
from controller.core.states import State
from controller.service.config import load_config
from controller.service.daemon import (
    STOP_MARGIN_FACTOR,
    STOP_MARGIN_S,
    STOP_WAIT_MAX_S,
    Notifier,
    StartupWatch,
    brake_wait_s,
    silent_nodes,
    zenoh_open_problem,
)
from controller.service.loop import Controller
from drivers.base import AxisReading
from drivers.bus import open_bus
from drivers.odrive import cansimple as cs
from tests.daemon_procs import CABLEBOT, Proc, udp_bus, write_config, zenoh_session, zquery
from tests.fakes import FakeClock, FakeDriver, make_config, power_up_turns

# ------------------------------------------------------------------------------ unit level


def test_brake_wait_follows_the_actual_speed_and_is_bounded() -> None:
    k = STOP_MARGIN_FACTOR
    assert brake_wait_s(2.0, 2.0, 1.0) == pytest.approx(2.0 * k + STOP_MARGIN_S)
    assert brake_wait_s(0.5, 2.0, 1.0) == pytest.approx(0.5 * k + STOP_MARGIN_S)
    assert brake_wait_s(0.0, 2.0, 1.0) == pytest.approx(STOP_MARGIN_S)
    # a stop along corner arcs brakes at their share of the acceleration: longer than v / a
    assert brake_wait_s(5.0, 2.0, 1.0) == pytest.approx(5.0 * k + STOP_MARGIN_S)
    # never longer than the slowest stop from the fastest allowed motion, nor the hard cap
    longest = 2.0 / BRAKE_ACCEL_SHARE
    assert brake_wait_s(50.0, 2.0, 1.0) == pytest.approx(longest * k + STOP_MARGIN_S)
    assert brake_wait_s(100.0, 2.0, 0.01) == STOP_WAIT_MAX_S
    assert brake_wait_s(math.nan, 2.0, 1.0) == STOP_WAIT_MAX_S


def test_zenoh_start_up_errors_name_the_keys_and_blame_another_daemon_only_when_it_fits() -> None:
    class Z:
        listen = ("tcp/127.0.0.1:7447",)
        connect = ()
        config_file = "/etc/cablebot/z.json5"

    taken = zenoh_open_problem(Z(), RuntimeError("bound: Address already in use (os error 98)"))
    assert "[zenoh] listen = ['tcp/127.0.0.1:7447'], config_file = '/etc/cablebot/z.json5'" in (
        taken
    )
    assert "is another cablebot daemon running?" in taken
    bad = zenoh_open_problem(Z(), RuntimeError("invalid port value"))
    assert "invalid port value" in bad and "[zenoh] listen" in bad
    assert "another cablebot daemon" not in bad


def test_silent_nodes_names_what_is_missing() -> None:
    readings = [
        AxisReading(4, stamp_s=1.0, heartbeat_stamp_s=1.0),
        AxisReading(5, heartbeat_stamp_s=1.0),
        AxisReading(6),
    ]
    assert silent_nodes(readings) == [
        (5, 2, "no encoder estimate"),
        (6, 3, "no heartbeat and no encoder estimate"),
    ]


class RecordingNotifier(Notifier):
    def __init__(self) -> None:
        super().__init__(env={})
        self.sent: list[str] = []

    def notify(self, message: str) -> None:
        self.sent.append(message)


class StubController:
    """The parts of Controller that StartupWatch uses; Arm resolves when the test says."""

    def __init__(self) -> None:
        self.state = State.DISARMED
        self.reason: str | None = None
        self.submitted: list[tuple[object, concurrent.futures.Future[dict[str, Any]]]] = []

    def submit(self, cmd: object) -> concurrent.futures.Future[dict[str, Any]]:
        fut: concurrent.futures.Future[dict[str, Any]] = concurrent.futures.Future()
        self.submitted.append((cmd, fut))
        return fut

    def status(self) -> dict[str, Any]:
        loop = {"rate_hz": 500.0, "ticks": 0, "overruns": 0}
        loop |= {"jitter_p99_s": None, "compute_p99_s": None}
        return {"state": self.state.value, "reason": None, "pose": {"valid": False}, "loop": loop}


def _answer(driver: FakeDriver, nodes: Sequence[int], now_s: float, **fields: int) -> None:
    for r in driver.readings:
        if r.node_id in nodes:
            r.stamp_s = r.heartbeat_stamp_s = now_s
            for k, v in fields.items():
                setattr(r, k, v)


def _watch(
    want_arm: bool, caplog: pytest.LogCaptureFixture
) -> tuple[StartupWatch, FakeClock, FakeDriver, StubController, RecordingNotifier]:
    cfg = make_config()  # faults.arm_timeout_s = 2 s
    clock = FakeClock()
    driver = FakeDriver(cfg.node_ids, clock)
    ctl = StubController()
    notifier = RecordingNotifier()
    caplog.set_level(logging.INFO, logger="cablebot.daemon")
    watch = StartupWatch(
        cfg, ctl, driver, notifier, want_arm=want_arm, status_every_s=1.0, clock=clock
    )
    return watch, clock, driver, ctl, notifier


def _run(watch: StartupWatch, clock: FakeClock, seconds: float) -> list[bool]:
    out = []
    for _ in range(round(seconds / 0.05)):
        clock.advance(0.05)
        out.append(watch.step())
    return out


def _silent_warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [
        r.getMessage()
        for r in caplog.records
        if r.levelno == logging.WARNING and "no answer from" in r.getMessage()
    ]


def test_startup_watch_names_silent_nodes_at_a_bounded_rate_and_withholds_ready(
    caplog: pytest.LogCaptureFixture,
) -> None:
    watch, clock, driver, _ctl, notifier = _watch(False, caplog)
    assert not any(_run(watch, clock, 5.5))
    w = _silent_warnings(caplog)
    assert len(w) == 4, w  # at 2 s (arm_timeout_s), then every status period (1 s)
    for n in range(4):
        assert f"node {n} (cable {n + 1}: no heartbeat and no encoder estimate)" in w[0]
    assert "virtual cablebot-default" in w[0] and "READY withheld" in w[0]
    assert "STATUS=waiting for ODrive node(s) [0, 1, 2, 3]" in notifier.sent
    _answer(driver, [0, 1, 2], clock())
    driver.readings[3].heartbeat_stamp_s = clock()  # node 3: heartbeats but no encoder
    assert not any(_run(watch, clock, 1.0))
    w = _silent_warnings(caplog)
    assert len(w) == 5 and "node 0" not in w[-1], w
    assert "node 3 (cable 4: no encoder estimate)" in w[-1]
    assert "READY=1" not in notifier.sent
    _answer(driver, [3], clock())
    assert _run(watch, clock, 0.1) == [True, False]
    assert notifier.sent.count("READY=1") == 1
    assert notifier.sent[-2:] == ["STATUS=DISARMED", "READY=1"]
    infos = [r.getMessage() for r in caplog.records if "answered after" in r.getMessage()]
    assert [m.split(" answered")[0] for m in infos] == [f"ODrive node {n}" for n in range(4)]
    assert not any(_run(watch, clock, 3.0))
    assert len(_silent_warnings(caplog)) == 5  # quiet once every reel answered


def test_startup_watch_auto_arms_only_once_every_reel_answered_and_ready_after_the_arm(
    caplog: pytest.LogCaptureFixture,
) -> None:
    watch, clock, driver, ctl, notifier = _watch(True, caplog)
    _answer(driver, [0, 1, 2], clock())
    assert not any(_run(watch, clock, 1.0))
    assert ctl.submitted == []  # node 3 silent: no arm
    _answer(driver, [3], clock())
    assert not any(_run(watch, clock, 0.2))
    assert len(ctl.submitted) == 1 and isinstance(ctl.submitted[0][0], Arm)
    ctl.state = State.ARMING
    ctl.submitted[0][1].set_result({"ok": True, "state": "ARMING"})
    assert not any(_run(watch, clock, 0.5))  # still arming: not ready
    ctl.state = State.HOLDING
    assert _run(watch, clock, 0.1) == [True, False]
    assert "STATUS=HOLDING" in notifier.sent
    assert notifier.sent.index("STATUS=HOLDING") < notifier.sent.index("READY=1")
    assert len(ctl.submitted) == 1
    # A refused auto-arm (not homed, say): the daemon is up all the same, and says why.
    watch, clock, driver, ctl, notifier = _watch(True, caplog)
    _answer(driver, [0, 1, 2, 3], clock())
    _run(watch, clock, 0.1)
    ctl.submitted[0][1].set_exception(CommandRefused("not homed: run `home` first"))
    assert any(_run(watch, clock, 0.1))
    assert any("auto-arm refused: not homed" in r.getMessage() for r in caplog.records)


def test_startup_watch_reads_each_node_first_heartbeat(caplog: pytest.LogCaptureFixture) -> None:
    watch, clock, driver, _ctl, _notifier = _watch(False, caplog)
    _answer(driver, [0], clock(), axis_state=8)
    _answer(driver, [1], clock(), axis_state=1, axis_error=0x1000000)
    _answer(driver, [2, 3], clock(), axis_state=1)
    _run(watch, clock, 0.5)
    msgs = [(r.levelno, r.getMessage()) for r in caplog.records if "ODrive node" in r.getMessage()]
    assert msgs == [
        (
            logging.WARNING,
            "ODrive node 0 is in closed loop before cablebot armed it: another controller "
            "drives it, or its watchdog (axis.config.enable_watchdog) is off and a previous "
            "controller left it running",
        ),
        (
            logging.INFO,
            "ODrive node 1 reports WATCHDOG_TIMER_EXPIRED: its watchdog stopped it after the "
            "previous controller went quiet (arming clears it)",
        ),
    ]


class _Floor:
    def check_point(self, p: Sequence[float]) -> str | None:
        return f"z={p[2]:.4g} m below the floor (0 m)" if p[2] < 0.0 else None


def _restored_warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if "the homing offsets from" in r.getMessage()]


def test_startup_watch_warns_once_about_a_pose_from_stale_state_file_offsets(
    caplog: pytest.LogCaptureFixture,
) -> None:
    watch, clock, driver, _ctl, _notifier = _watch(False, caplog)
    _answer(driver, [0, 1, 2, 3], clock())
    _run(watch, clock, 2.0)
    assert not _restored_warnings(caplog)  # the stub was not homed from a state file
    for pose, expect in (
        (None, "give no valid pose with the drives' readings"),
        ((0.0, 0.0, -1.3087), "[0.0000, 0.0000, -1.3087] m, outside the workspace (z=-1.309"),
    ):
        caplog.clear()
        state_ctl = StubController()
        state_ctl.home_source = "state_file"  # type: ignore[attr-defined]
        state_ctl.pose_m = pose  # type: ignore[attr-defined]
        state_ctl.pose_valid = pose is not None  # type: ignore[attr-defined]
        state_ctl.workspace = _Floor()  # type: ignore[attr-defined]
        watch = StartupWatch(
            make_config(),
            state_ctl,
            driver,
            RecordingNotifier(),
            want_arm=False,
            status_every_s=1.0,
            clock=clock,
        )
        _answer(driver, [0, 1, 2, 3], clock())
        _run(watch, clock, 0.5)
        if pose is None:  # the loop may not have solved it yet: no word within a second
            assert not _restored_warnings(caplog)
        _answer(driver, [0, 1, 2, 3], clock())
        _run(watch, clock, 1.0)
        warned = _restored_warnings(caplog)
        assert len(warned) == 1 and expect in warned[0], warned
        _run(watch, clock, 2.0)
        assert len(_restored_warnings(caplog)) == 1  # once


class FFDriver(FakeDriver):
    """A FakeDriver that records the velocity feed-forward of every command."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.ffs: list[tuple[float, ...]] = []

    def command(
        self, positions_rev: Sequence[float], velocity_ff_rps: Sequence[float] | None = None
    ) -> None:
        super().command(positions_rev, velocity_ff_rps)
        self.ffs.append(tuple(velocity_ff_rps) if velocity_ff_rps is not None else ())


def test_begin_shutdown_refuses_new_motion_brakes_at_max_accel_and_holds_without_feed_forward() -> (
    None
):
    cfg = make_config(loop={"rate_hz": 500.0})
    clock = FakeClock()
    driver = FFDriver(cfg.node_ids, clock, power_up_turns(cfg))
    ctl = Controller(cfg, driver, clock=clock, wall_clock_ns=clock.wall_ns)
    dt = 1.0 / 500.0

    def tick_until(pred: Callable[[], bool], limit_s: float) -> None:
        for _ in range(round(limit_s / dt)):
            clock.advance(dt)
            ctl.tick(clock())
            if pred():
                return
        raise AssertionError(f"not reached in {limit_s} s: {ctl.state} {ctl.reason}")

    tick_until(lambda: ctl.pose_valid, 1.0)
    ctl.submit(Arm())
    tick_until(lambda: ctl.state is State.HOLDING, 1.0)
    ctl.submit(Move((30.0, 0.0, 2.0), speed_mps=2.0))
    tick_until(lambda: ctl.brake_time_s() >= 2.0 - 1e-9, 3.0)  # cruising at max speed
    assert ctl.brake_time_s() == pytest.approx(2.0)
    at_signal = ctl.setpoint_m
    assert at_signal is not None
    ctl.begin_shutdown()
    late_move = ctl.submit(Move((-10.0, 0.0, 2.0)))
    ctl.submit_setpoint((-10.0, 5.0, 2.0))  # a streaming client that keeps sending
    tick_until(lambda: ctl.state is State.HOLDING, 3.0)
    with pytest.raises(CommandRefused, match="shutting down"):
        late_move.result(timeout=0)
    rest = ctl.setpoint_m
    assert rest is not None
    assert math.dist(at_signal, rest) == pytest.approx(2.0**2 / (2 * 1.0), abs=0.01)
    assert rest[0] > at_signal[0]  # braked straight on, the late commands were ignored
    assert all(v == 0.0 for v in driver.ffs[-1])
    assert ctl.send_final_hold()
    assert driver.commands[-1] == tuple(ctl.commanded_rev or ())
    assert driver.ffs[-1] == (0.0,) * 4


# ------------------------------------------------------------------------------ processes


# The host running the tests is shared and loaded: a starved simulator process must not fault
# the move (these faults have their own tests); what is measured here is the stopping.
LOADED_HOST_FAULTS = {"stale_timeout_s": 0.5, "heartbeat_timeout_s": 1.5, "tracking_max_m": 1.0}


class BusTap:
    """Every decodable CANSimple frame on the robot's bus, with the time the kernel received it
    (wall clock, `time.time()`'s; udp_multicast's SO_TIMESTAMPNS): a tap thread starved on a
    busy machine reads frames late, but their times stay those of the bus."""

    def __init__(self, bus: dict[str, Any]) -> None:
        self.bus = open_bus(bus["interface"], bus["channel"], None, **bus["options"])
        self.frames: list[tuple[float, cs.Message]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.05)
            if msg is None or msg.is_error_frame:
                continue
            m = cs.decode(msg.arbitration_id, msg.data, msg.is_remote_frame, msg.is_extended_id)
            if not isinstance(m, cs.DecodeError):
                self.frames.append((msg.timestamp, m))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.bus.shutdown()

    def of(self, kind: type, after_s: float = -math.inf, before_s: float = math.inf) -> list[Any]:
        return [m for t, m in list(self.frames) if isinstance(m, kind) and after_s < t < before_s]

    def latest(self, kind: type, nodes: Sequence[int], **window: float) -> dict[int, Any]:
        out: dict[int, Any] = {}
        for m in self.of(kind, **window):
            out[m.node_id] = m
        assert sorted(out) == sorted(nodes), (kind.__name__, sorted(out))
        return out

    def wait_for(self, kind: type, after_s: float, timeout_s: float) -> None:
        """Wait until a `kind` frame received after wall-clock time `after_s` was read."""
        deadline = time.monotonic() + timeout_s
        while not self.of(kind, after_s=after_s):
            assert time.monotonic() < deadline, f"no {kind.__name__} after {after_s}"
            time.sleep(0.01)


def _pose(cfg: Any, turns: dict[int, float]) -> tuple[float, float, float]:
    lengths = [r.reel.length_m(turns[r.node_id]) for r in cfg.reels]
    p = kinematics.fpk(cfg.geometry, lengths).position_m
    return (float(p[0]), float(p[1]), float(p[2]))


def _turns(encoders: dict[int, Any]) -> dict[int, float]:
    return {n: m.pos_estimate_rev for n, m in encoders.items()}


def _wait_status(
    session: Any, prefix: str, pred: Callable[[dict[str, Any]], bool], timeout_s: float
) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while True:
        st = zquery(session, f"{prefix}/status")
        if pred(st):
            return st
        assert time.monotonic() < deadline, (
            st.get("state"),
            st.get("reason"),
            st.get("setpoint_m"),
        )
        time.sleep(0.02)


def _cruise_at_max_speed(info: dict[str, Any]) -> Any:
    """Arm over Zenoh and start a 30 m move at max speed (2 m/s); return once the set-point
    cruises (past the 2 m acceleration phase). Returns the Zenoh session."""
    session = zenoh_session(info["endpoint"])
    prefix = info["prefix"]
    r = zquery(session, f"{prefix}/cmd/arm", {})
    assert r.get("ok") is True, r
    _wait_status(session, prefix, lambda s: s["state"] == "HOLDING", 10.0)
    r = zquery(session, f"{prefix}/cmd/move", {"position_m": [30.0, 0.0, 2.0], "speed_mps": 2.0})
    assert r.get("ok") is True, r
    _wait_status(
        session,
        prefix,
        lambda s: s["state"] == "MOVING" and (s["setpoint_m"] or [0.0])[0] > 3.0,
        10.0,
    )
    return session


@pytest.mark.slow
def test_sigterm_at_max_speed_brakes_to_rest_and_leaves_a_zero_feed_forward_hold(
    tmp_path: Path,
) -> None:
    bus = udp_bus()
    cfg_path, info = write_config(tmp_path, bus, faults=LOADED_HOST_FAULTS)
    cfg = load_config(cfg_path)
    nodes = list(cfg.node_ids)
    sim = Proc([*CABLEBOT, "sim", "--config", str(cfg_path)], "sim")
    tap: BusTap | None = None
    daemon: Proc | None = None
    try:
        sim.wait_line("READY", 20)
        tap = BusTap(bus)
        daemon = Proc([*CABLEBOT, "run", "--config", str(cfg_path)], "daemon")
        daemon.wait_line("ready:", 20, stderr=True)
        session = _cruise_at_max_speed(info)
        session.close()
        t_term = time.time()
        daemon.p.send_signal(signal.SIGTERM)
        assert daemon.p.wait(15) == 0, daemon.log()
        t_exit = time.time()
        # v/a = 2 s of braking, the margin, closing: well inside systemd's TimeoutStopSec.
        assert t_exit - t_term < 2.0 * STOP_MARGIN_FACTOR + STOP_MARGIN_S + 3.0, daemon.log()
        braked = daemon.wait_line("braked from", 2, stderr=True)
        assert "braked from 2.000 m/s" in braked, braked
        daemon.wait_line("final hold sent", 2, stderr=True)
        # What the drives were told last, and where they came to rest.
        tap.wait_for(cs.EncoderEstimates, after_s=t_exit + 0.5, timeout_s=5.0)
        last_cmd = tap.latest(cs.SetInputPos, nodes)
        assert all(m.vel_ff_rps == 0.0 for m in last_cmd.values()), last_cmd
        rest = tap.latest(cs.EncoderEstimates, nodes, after_s=t_exit + 0.4)
        assert all(abs(m.vel_estimate_rps) < 1e-3 for m in rest.values()), rest
        for n in nodes:  # on the last set-point (not vel_ff / pos_gain past it)
            assert abs(rest[n].pos_estimate_rev - last_cmd[n].input_pos_rev) < 2e-3, n
        at_term = tap.latest(cs.EncoderEstimates, nodes, before_s=t_term)
        p0, p1 = _pose(cfg, _turns(at_term)), _pose(cfg, _turns(rest))
        distance = math.dist(p0, p1)
        # The drives' own speed when the daemon exited, and once settled on the final hold
        # (before their watchdog idles them, 0.3 s after the last command).
        at_exit = tap.latest(cs.EncoderEstimates, nodes, before_s=t_exit)
        exit_speed = max(abs(m.vel_estimate_rps) for m in at_exit.values())
        settled = tap.of(cs.EncoderEstimates, after_s=t_exit + 0.15, before_s=t_exit + 0.25)
        assert {m.node_id for m in settled} == set(nodes)
        settled_speed = max(abs(m.vel_estimate_rps) for m in settled)
        mps_per_rps = max(
            abs(r.reel.length_rate_mps(rest[r.node_id].pos_estimate_rev, 1.0)) for r in cfg.reels
        )
        assert exit_speed < 0.1, at_exit  # the end of the approach to the final set-point
        assert settled_speed < 0.01, settled
        print(
            f"\nSIGTERM at 2 m/s: braked over {distance:.3f} m (v^2/2a = 2.000 m), rest at "
            f"{p1[0]:.4f} m; motor speed at exit {exit_speed:.3g} rev/s "
            f"({exit_speed * mps_per_rps * 1e3:.2f} mm/s of cable), settled on the hold "
            f"{settled_speed:.2g} rev/s; exit after {t_exit - t_term:.2f} s; "
            f"{braked.split(': ', 1)[-1]}"
        )
        assert distance == pytest.approx(2.0, abs=0.25)
        assert p1[0] > p0[0]
    finally:
        if tap is not None:
            tap.close()
        if daemon is not None:
            daemon.kill()
        assert sim.terminate() == 0, sim.log()


@pytest.mark.slow
def test_kill_9_mid_move_leaves_the_axes_idle_and_still_within_the_watchdog_time(
    tmp_path: Path,
) -> None:
    bus = udp_bus()
    cfg_path, info = write_config(tmp_path, bus, faults=LOADED_HOST_FAULTS)
    cfg = load_config(cfg_path)
    nodes = list(cfg.node_ids)
    watchdog_s = cfg.sim.watchdog_timeout_s
    assert watchdog_s == 0.3
    sim = Proc([*CABLEBOT, "sim", "--config", str(cfg_path)], "sim")
    tap: BusTap | None = None
    daemon: Proc | None = None
    try:
        sim.wait_line("READY", 20)
        tap = BusTap(bus)
        daemon = Proc([*CABLEBOT, "run", "--config", str(cfg_path)], "daemon")
        daemon.wait_line("ready:", 20, stderr=True)
        session = _cruise_at_max_speed(info)
        session.close()
        t_kill = time.time()
        daemon.p.send_signal(signal.SIGKILL)
        daemon.p.wait(5)
        at_kill = tap.latest(cs.EncoderEstimates, nodes, before_s=t_kill)
        assert all(abs(m.vel_estimate_rps) > 1.0 for m in at_kill.values()), at_kill
        closed = tap.latest(cs.Heartbeat, nodes, before_s=t_kill)
        assert all(m.axis_state == cs.AxisState.CLOSED_LOOP_CONTROL for m in closed.values())
        # Every axis reports IDLE with the watchdog error, and its encoder stands still.
        deadline = t_kill + 5.0
        stopped_at: float | None = None
        while stopped_at is None:
            assert time.time() < deadline, (tap.latest(cs.Heartbeat, nodes), sim.log())
            hb = {m.node_id: (t, m) for t, m in list(tap.frames) if isinstance(m, cs.Heartbeat)}
            enc = {
                m.node_id: (t, m) for t, m in list(tap.frames) if isinstance(m, cs.EncoderEstimates)
            }
            if len(hb) == len(nodes) and all(
                m.axis_state == cs.AxisState.IDLE
                and m.axis_error & cs.ODriveError.WATCHDOG_TIMER_EXPIRED
                and enc[n][1].vel_estimate_rps == 0.0
                for n, (_, m) in hb.items()
            ):
                stopped_at = max(max(t for t, _ in hb.values()), max(t for t, _ in enc.values()))
            else:
                time.sleep(0.01)
        # The heartbeat that reports IDLE comes up to one heartbeat period after the expiry.
        idle_after = stopped_at - t_kill
        tap.wait_for(cs.EncoderEstimates, after_s=stopped_at + 0.2, timeout_s=5.0)
        rest = tap.latest(cs.EncoderEstimates, nodes, after_s=stopped_at + 0.1)
        assert all(m.vel_estimate_rps == 0.0 for m in rest.values())
        # The travel is counted from the kill as the bus saw it, the daemon's last command:
        # each axis's last encoder estimate before that frame, in the order the frames went by
        # (this process may read them late on a busy machine, so its clock at the kill can
        # fall well after the estimate it last read).
        frames = [m for _, m in list(tap.frames)]
        last_cmd = max(i for i, m in enumerate(frames) if isinstance(m, cs.SetInputPos))
        on_kill = {m.node_id: m for m in frames[:last_cmd] if isinstance(m, cs.EncoderEstimates)}
        assert sorted(on_kill) == sorted(nodes), on_kill
        assert all(abs(m.vel_estimate_rps) > 1.0 for m in on_kill.values()), on_kill
        travel = math.dist(_pose(cfg, _turns(on_kill)), _pose(cfg, _turns(rest)))
        print(
            f"\nkill -9 at 2 m/s: all axes IDLE (WATCHDOG_TIMER_EXPIRED), velocity 0, "
            f"{idle_after:.3f} s after the kill (watchdog {watchdog_s} s, heartbeat "
            f"{cfg.sim.heartbeat_period_s} s); travel after the kill {travel:.3f} m"
        )
        assert idle_after < watchdog_s + cfg.sim.heartbeat_period_s + 0.5
        assert travel < 2.0 * (watchdog_s + 0.1)  # at most the watchdog time at 2 m/s
        # A restarted daemon sees what the watchdog did, and can arm again.
        daemon = Proc([*CABLEBOT, "run", "--config", str(cfg_path)], "daemon")
        daemon.wait_line("reports WATCHDOG_TIMER_EXPIRED", 20, stderr=True)
        daemon.wait_line("ready:", 20, stderr=True)
        session = zenoh_session(info["endpoint"])
        try:
            r = zquery(session, f"{info['prefix']}/cmd/arm", {})
            assert r.get("ok") is True, r
            _wait_status(session, info["prefix"], lambda s: s["state"] == "HOLDING", 10.0)
        finally:
            session.close()
        assert daemon.terminate() == 0, daemon.log()
    finally:
        if tap is not None:
            tap.close()
        if daemon is not None:
            daemon.kill()
        assert sim.terminate() == 0, sim.log()


def _sim_nodes(bus: dict[str, Any], cfg: Any, nodes: Sequence[int]) -> Proc:
    turns = dict(zip(cfg.node_ids, power_up_turns(cfg), strict=True))
    return Proc(
        [
            sys.executable,
            "-m",
            "drivers.odrive.sim",
            "--interface",
            bus["interface"],
            "--channel",
            bus["channel"],
            "--port",
            str(bus["options"]["port"]),
            "--option",
            "hop_limit=0",
            "--nodes",
            ",".join(map(str, nodes)),
            "--initial-rev",
            ",".join(repr(turns[n]) for n in nodes),
            "--encoder-period-s",
            "0.002",
            "--watchdog-timeout-s",
            "0.3",
        ],
        f"sim{nodes}",
    )


@pytest.mark.slow
def test_ready_waits_for_every_reel_and_silent_nodes_are_named_until_they_answer(
    tmp_path: Path,
) -> None:
    bus = udp_bus()
    cfg_path, _info = write_config(
        tmp_path, bus, faults={"arm_timeout_s": 0.5}, loop={"auto_arm": True}
    )
    cfg = load_config(cfg_path)
    sock_path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(sock_path)
    sock.settimeout(0.05)
    got: list[str] = []

    def listen(seconds: float, until: str | None = None) -> None:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and (until is None or until not in got):
            with contextlib.suppress(TimeoutError):
                got.append(sock.recv(4096).decode())

    def warnings() -> list[str]:
        return [line for line in daemon.err if "WARNING" in line and "no answer from" in line]

    env = {"NOTIFY_SOCKET": sock_path}
    daemon = Proc(
        [*CABLEBOT, "run", "--config", str(cfg_path), "--status-every", "1"], "daemon", env=env
    )
    sims: list[Proc] = []
    try:
        t0 = time.monotonic()
        # two warnings: a second apart once the daemon is up (its start-up takes seconds on a
        # loaded host)
        start_deadline = t0 + 60.0
        while len(warnings()) < 2:
            assert time.monotonic() < start_deadline, daemon.log()
            listen(0.1)
        assert "READY=1" not in got, daemon.log()
        w = warnings()
        elapsed = time.monotonic() - t0
        assert 2 <= len(w) <= elapsed / 1.0 + 1, w  # repeated, at most once a second
        for n in range(4):
            assert f"node {n} (cable {n + 1}: no heartbeat and no encoder estimate)" in w[-1], w
        assert "READY withheld" in w[-1]
        assert not any("auto-arm requested" in line for line in daemon.err)
        # Three of four reels answer: only the fourth is named now, READY still withheld.
        sims.append(_sim_nodes(bus, cfg, [0, 1, 2]))
        seen = len(w)
        deadline = time.monotonic() + 15.0
        while not any("node 0" not in line for line in warnings()[seen:]):
            assert time.monotonic() < deadline, daemon.log()
            listen(0.1)
        latest = [line for line in warnings()[seen:] if "node 0" not in line][-1]
        assert "node 3 (cable 4:" in latest and "node 1" not in latest, latest
        assert "READY=1" not in got
        # The last one answers: auto-arm, then READY once the robot holds.
        sims.append(_sim_nodes(bus, cfg, [3]))
        listen(20.0, until="READY=1")
        assert "READY=1" in got, daemon.log()
        ready_at = got.index("READY=1")
        assert any(m.startswith("STATUS=HOLDING") for m in got[:ready_at]), got
        daemon.wait_line("ODrive node 3 answered after", 2, stderr=True)
        n_warnings = len(warnings())
        listen(1.5)
        assert len(warnings()) == n_warnings  # quiet once every reel answers
    finally:
        daemon.kill()
        for p in sims:
            p.terminate()
        sock.close()
