"""The pre-tension in the control step (fake clock, fake torque-capable driver): torque
control at the statics tensions of the home pose, ramped; home declared when the reels are
still; faults for travel, time, axes; stop, disarm and estop leave torque control."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from controller.core import kinematics
from controller.core.commands import Disarm, Estop, Move, Pretension, Stop
from controller.core.states import State
from controller.core.statics import solve_tensions
from controller.service.config import load_config
from tests.fakes import make_config
from tests.service.test_loop import DT, RATE_HZ, Rig

REPO = Path(__file__).resolve().parents[2]
SETTLE_S = 2.0  # the default
SETTLE_TICKS = int((SETTLE_S + 0.5) * RATE_HZ)


def _statics(rig: Rig, p: tuple[float, float, float]) -> tuple[float, ...]:
    cfg = rig.cfg
    t = cfg.tension
    return solve_tensions(cfg.anchors_m, p, cfg.payload.mass_kg, t.min_n, t.max_n).tensions_n


def _rig_cfg(**homing: Any) -> Any:
    """The built-in robot on real (fake) drives: its kinematic simulator off, a real bus."""
    cfg = make_config(
        loop={"rate_hz": RATE_HZ},
        sim={"enabled": False},
        bus={"interface": "socketcan", "channel": "can0"},
    )
    return replace(cfg, homing=replace(cfg.homing, **homing)) if homing else cfg


def _armed_rig(**kw: Any) -> Rig:
    rig = Rig(**{"cfg": _rig_cfg(), **kw})
    rig.arm()
    return rig


def test_pretension_pulls_with_the_statics_torques_then_homes_where_the_reels_rest() -> None:
    rig = _armed_rig()
    p = rig.start
    reply = rig.do(Pretension(p))
    assert rig.state() is State.PRETENSIONING
    assert reply["state"] == "PRETENSIONING" and reply["speed_limited"] is True
    tensions = _statics(rig, p)
    assert reply["tensions_n"] == pytest.approx(tensions, rel=1e-9)
    assert reply["tensions_n"] == pytest.approx([104.4422] * 4, abs=1e-3)  # 5 kg at (0, 0, 2)
    reels = rig.ctl.reels
    pos = [r.position_rev for r in rig.driver.readings]
    want = [reels[i].torque_nm(pos[i], tensions[i]) for i in range(4)]
    assert reply["torques_nm"] == pytest.approx(want)
    assert all(t < 0.0 for t in want)  # positive turns pay out: the holding torque winds in
    # the drives may turn at most 0.05 m/s of cable: 1 rev/s on 0.05 m per motor turn
    assert rig.driver.velocity_limits_rps == pytest.approx([1.0] * 4)
    assert "enter_torque_mode" in rig.driver.calls

    # the reels wind in (slack taken up) for 0.7 s: the cables shorten by 14 mm
    rig.driver.torque_velocity_rps = [-0.4] * 4
    rig.tick(int(0.7 * RATE_HZ))
    assert rig.state() is State.PRETENSIONING
    # the full torques from the start, set before torque control begins (no reel ever pulls
    # with zero: a reel that carries the payload would pay out and the effector drop)
    assert rig.driver.calls.count("enter_torque_mode") == 1
    assert all(t == pytest.approx(want) for t in rig.driver.torques)
    rig.driver.torque_velocity_rps = [0.0] * 4
    n = rig.until(lambda: rig.state() is not State.PRETENSIONING, 2 * SETTLE_TICKS)
    assert rig.driver.torques[-1] == pytest.approx(want)
    assert n >= int(SETTLE_S * RATE_HZ) - 2  # still for settle_s before the home is declared
    assert rig.state() is State.HOLDING, rig.ctl.reason
    assert rig.ctl.home_source == "pretension"
    # in the very tick it homes, the pose is the home pose (not the old offsets' pose of the
    # wound-in cables, 14 mm shorter)
    assert rig.ctl.pose_m == p and rig.ctl.residual_m == 0.0
    assert rig.ctl.status()["pose"]["position_m"] == list(p)
    assert "leave_torque_mode" in rig.driver.calls
    # declared at p: the encoders now say p, and the motors hold the turns they rest at
    rest = [r.position_rev for r in rig.driver.readings]
    assert rest == pytest.approx([x - 0.4 * 0.7 for x in pos], abs=0.01)
    rig.tick(5)
    assert rig.ctl.pose_valid and math.dist(rig.ctl.pose_m, p) < 1e-6
    assert rig.driver.commands[-1] == pytest.approx(rest, abs=1e-9)
    lengths = kinematics.ipk_point(rig.ctl.geometry, p)
    for reel, r, length in zip(rig.ctl.reels, rig.driver.readings, lengths, strict=True):
        assert reel.length_m(r.position_rev) == pytest.approx(length, abs=1e-9)
    st = rig.ctl.status()["pretension"]
    assert st["active"] is False
    res = st["result"]
    assert res["ok"] is True and res["position_m"] == list(p)
    assert res["still_after_s"] == pytest.approx(0.7 + SETTLE_S, abs=0.05)
    assert set(res["offsets_rev"]) == {str(n) for n in rig.ctl.node_ids}
    # and the robot moves as usual
    rig.do(Move((p[0] + 0.5, p[1], p[2])))
    assert rig.state() is State.MOVING


def test_the_result_says_saving_until_the_offsets_are_on_disk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The offsets are saved off the loop thread; on a loaded host the fsync takes a while. Until
    # it is done the published result says "saving" (a client that read "saved": False then
    # told its user there was no state file at all).
    import threading

    from controller.service import offsets

    release = threading.Event()
    real = offsets.save_offsets

    def slow_save(path: Any, state: Any) -> None:
        assert release.wait(30.0)
        real(path, state)

    monkeypatch.setattr(offsets, "save_offsets", slow_save)
    state_file = tmp_path / "offsets.json"
    rig = Rig(cfg=_rig_cfg(state_file=str(state_file)))
    rig.arm()
    rig.do(Pretension(rig.start))
    rig.until(lambda: rig.state() is not State.PRETENSIONING, 2 * SETTLE_TICKS)
    assert rig.state() is State.HOLDING, rig.ctl.reason
    res = rig.ctl.status()["pretension"]["result"]
    assert res["ok"] is True and res["saving"] is True and res["saved"] is False
    assert res["state_file"] == str(state_file) and not state_file.exists()
    release.set()
    rig.ctl.wait_for_saves(30.0)
    res = rig.ctl.status()["pretension"]["result"]
    assert res["saved"] is True and "saving" not in res and state_file.exists()


def test_pretension_from_disarmed_arms_in_torque_control() -> None:
    rig = Rig(_rig_cfg())
    rig.tick(2)
    assert rig.state() is State.DISARMED and not rig.driver.armed
    rig.do(Pretension(rig.start))
    assert rig.state() is State.PRETENSIONING and rig.driver.torque_mode
    rig.until(lambda: rig.state() is not State.PRETENSIONING, 2 * SETTLE_TICKS)
    assert rig.state() is State.HOLDING, rig.ctl.reason
    assert not rig.driver.torque_mode


def test_status_reports_the_running_pretension() -> None:
    rig = _armed_rig()
    rig.do(Pretension(rig.start))
    rig.driver.torque_velocity_rps = [0.0, -0.2, 0.0, 0.0]
    rig.tick(50)
    st = rig.ctl.status()["pretension"]
    assert st["active"] is True and st["position_m"] == list(rig.start)
    assert st["tensions_n"] == pytest.approx([104.4422] * 4, abs=1e-3)
    assert st["elapsed_s"] == pytest.approx(51 * DT, abs=2 * DT)
    assert st["fastest_cable_mps"] == pytest.approx(0.2 * 0.05)
    assert st["result"] is None


def test_a_reel_that_winds_on_and_on_faults_and_holds_where_it_is() -> None:
    rig = _armed_rig()
    rig.do(Pretension(rig.start))
    rig.driver.torque_velocity_rps = [0.0, 0.0, -4.0, 0.0]  # 0.2 m/s of cable: no end
    rig.until(lambda: rig.state() is not State.PRETENSIONING, int(5 * RATE_HZ))
    assert rig.state() is State.FAULT
    reason = rig.ctl.reason or ""
    assert reason.startswith("pretension: cable 3 moved 0.50"), reason
    assert "homing.pretension_max_travel_m 0.5 m" in reason
    assert not rig.driver.torque_mode and "leave_torque_mode" in rig.driver.calls
    # FAULT keeps commanding the turns the reels were at when it faulted
    rig.tick(3)
    held = [r.position_rev for r in rig.driver.readings]
    assert rig.driver.commands[-1] == pytest.approx(held, abs=1e-9)
    assert rig.ctl.status()["pretension"]["result"] == {"ok": False, "reason": reason}


def test_reels_that_never_come_still_fault_at_the_timeout() -> None:
    rig = _armed_rig(cfg=_rig_cfg(pretension_timeout_s=2.0))
    rig.do(Pretension(rig.start))
    ticks = 0
    while rig.state() is State.PRETENSIONING:
        sign = 1.0 if ticks % 50 < 25 else -1.0  # a swing: no travel, never still
        rig.driver.torque_velocity_rps = [0.0, sign * 0.2, 0.0, 0.0]
        rig.tick()
        ticks += 1
        assert ticks < 3 * RATE_HZ
    assert ticks * DT == pytest.approx(2.0, abs=0.05)
    reason = rig.ctl.reason or ""
    assert rig.state() is State.FAULT
    assert reason.startswith("pretension: not still after 2 s (homing.pretension_timeout_s)")
    assert "cable 2 at 10 mm/s" in reason


def test_slack_cables_do_not_fault_on_the_residual_while_pretensioning() -> None:
    rig = _armed_rig()
    rig.do(Pretension(rig.start))
    rig.driver.torque_velocity_rps = [-4.0, 0.0, 0.0, 0.0]  # cable 1 winds in 0.2 m/s
    rig.tick(int(0.5 * RATE_HZ))  # 10 cm: the four lengths no longer meet at one point
    assert rig.ctl.residual_m is not None and rig.ctl.residual_m > 0.02
    assert rig.state() is State.PRETENSIONING, rig.ctl.reason


def test_stop_ends_the_pretension_holding_where_the_reels_are() -> None:
    rig = _armed_rig()
    rig.do(Pretension(rig.start))
    rig.driver.torque_velocity_rps = [-0.2] * 4
    rig.tick(20)
    reply = rig.do(Stop())
    assert reply["state"] == "HOLDING" and rig.state() is State.HOLDING
    assert rig.ctl.reason == "pretension stopped: holding where the reels are"
    assert not rig.driver.torque_mode
    assert rig.ctl.status()["pretension"]["result"] == {"ok": False, "reason": "stopped"}
    assert rig.ctl.home_source == "power_up"  # not homed by a pre-tension that did not end


@pytest.mark.parametrize(
    ("cmd", "state", "last_call"),
    [(Disarm(), State.DISARMED, "disarm"), (Estop(), State.ESTOPPED, "leave_torque_mode")],
)
def test_disarm_and_estop_end_the_pretension(cmd: Any, state: State, last_call: str) -> None:
    rig = _armed_rig()
    rig.do(Pretension(rig.start))
    rig.tick(10)
    rig.ctl.submit(cmd)
    rig.tick()
    assert rig.state() is state
    calls = rig.driver.calls
    assert "leave_torque_mode" in calls and calls[-1] == last_call
    if isinstance(cmd, Estop):  # the Estop goes out first, the velocity limits come back after
        assert calls.index("estop") < len(calls) - 1
    assert rig.ctl.status()["pretension"]["result"]["ok"] is False
    n = len(rig.driver.torques)
    rig.tick(10)
    assert len(rig.driver.torques) == n  # no torque after it


def test_an_axis_fault_during_the_pretension_faults() -> None:
    rig = _armed_rig()
    rig.do(Pretension(rig.start))
    rig.tick(10)
    rig.driver.axis_error[rig.ctl.node_ids[2]] = 0x800
    rig.tick(2)
    assert rig.state() is State.FAULT
    assert (rig.ctl.reason or "").startswith(f"axis_error: node {rig.ctl.node_ids[2]}")
    assert "leave_torque_mode" in rig.driver.calls


def test_pretension_is_refused_without_a_payload() -> None:
    cfg = replace(_rig_cfg(), payload=None, tension=None)
    rig = _armed_rig(cfg=cfg)
    why = rig.refused(Pretension(rig.start))
    assert "needs [payload] mass_kg" in why
    assert rig.state() is State.HOLDING and "enter_torque_mode" not in rig.driver.calls


class _PositionOnly:
    """A driver with position control only (no `TorqueDriver` methods)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.node_ids = inner.node_ids

    def poll(self) -> int:
        return int(self.inner.poll())

    def read(self) -> Any:
        return self.inner.read()

    def command(self, positions_rev: Any, velocity_ff_rps: Any = None) -> None:
        self.inner.command(positions_rev, velocity_ff_rps)

    def arm(self) -> None:
        self.inner.arm()

    def disarm(self) -> None:
        self.inner.disarm()

    def estop(self) -> None:
        self.inner.estop()

    def request_encoders(self) -> None:
        self.inner.request_encoders()

    @property
    def stats(self) -> Any:
        return self.inner.stats


def test_pretension_is_refused_for_drives_without_torque_control() -> None:
    rig = _armed_rig()
    rig.ctl.driver = _PositionOnly(rig.driver)
    why = rig.refused(Pretension(rig.start))
    assert "no torque control for odrive drives" in why and "home without --pretension" in why
    assert rig.state() is State.HOLDING


def test_pretension_outside_the_limits_or_with_stale_encoders_is_refused() -> None:
    rig = _armed_rig()
    s = rig.start
    why = rig.refused(Pretension((s[0], s[1], 7.5)))  # 0.12 m under the anchors
    assert why.startswith("home position [0.0000, 0.0000, 7.5000]: z=7.5 m above"), why
    assert rig.state() is State.HOLDING
    rig = Rig(_rig_cfg())  # disarmed: a stale encoder refuses it (armed, it faults first)
    rig.tick(2)
    rig.driver.silent = {rig.ctl.node_ids[1]}
    rig.clock.advance(0.2)
    why = rig.refused(Pretension(s))
    assert why.startswith("stale_encoder: no fresh encoder reading (node 1"), why
    assert "enter_torque_mode" not in rig.driver.calls


def test_pretension_is_refused_on_the_kinematic_simulator() -> None:
    rig = Rig()  # the built-in robot: in-process simulated reels with nothing hanging on them
    rig.arm()
    why = rig.refused(Pretension(rig.start))
    assert why.startswith(
        "pretension: the reels are the kinematic simulator's (simulated drives on virtual "
        'cablebot-default, run in the daemon, [sim] plant = "kinematic"): it carries no load'
    ), why
    assert 'give the robot file [sim] plant = "physical"' in why
    assert rig.state() is State.HOLDING


def test_pretension_is_refused_on_the_kinematic_simulator_of_another_process() -> None:
    """The shipped paper robot's reels: `cablebot sim` runs them on a udp_multicast bus with
    the kinematic plant; the daemon knows it from the robot file and refuses before anything
    moves (no torque mode entered)."""
    cfg = load_config(REPO / "config" / "paper-acre.toml")
    assert not cfg.sim.enabled and cfg.sim.plant == "kinematic" and cfg.kinematic_sim
    rig = Rig(replace(cfg, loop=replace(cfg.loop, rate_hz=RATE_HZ, realtime=False)))
    rig.arm()
    why = rig.refused(Pretension(rig.start))
    assert why.startswith(
        "pretension: the reels are the kinematic simulator's (simulated drives on "
        "udp_multicast 239.74.0.1, run by `cablebot sim`"
    ), why
    assert "enter_torque_mode" not in rig.driver.calls
    assert rig.state() is State.HOLDING
    physical = replace(cfg, sim=replace(cfg.sim, plant="physical"))
    assert not physical.kinematic_sim


def test_an_axis_that_does_not_enter_closed_loop_faults_after_the_arm_timeout() -> None:
    rig = Rig(_rig_cfg())
    rig.tick(2)
    node = rig.ctl.node_ids[2]
    rig.driver.no_closed_loop = {node}
    rig.do(Pretension(rig.start))
    rig.until(lambda: rig.state() is not State.PRETENSIONING, int(3 * RATE_HZ))
    assert rig.state() is State.FAULT
    assert rig.ctl.reason == f"pretension: node {node} not in closed loop after 2 s (IDLE)"
    assert "leave_torque_mode" in rig.driver.calls


def test_pretension_homes_an_unhomed_robot_and_stop_before_the_end_faults_holding() -> None:
    # No power-up pose and no state file: the pre-tension is how this robot gets homed.
    rig = Rig(_rig_cfg(power_up_position_m=None), homed=False)
    rig.tick(2)
    assert not rig.ctl.homed and not rig.ctl.pose_valid
    p = (0.0, 0.0, 2.0)
    rig.do(Pretension(p))
    rig.until(lambda: rig.state() is not State.PRETENSIONING, 2 * SETTLE_TICKS)
    assert rig.state() is State.HOLDING and rig.ctl.home_source == "pretension"
    assert rig.ctl.pose_m == p

    rig = Rig(_rig_cfg(power_up_position_m=None), homed=False)
    rig.tick(2)
    rig.do(Pretension(p))
    rig.tick(10)
    reply = rig.do(Stop())
    assert reply["state"] == "FAULT" and rig.state() is State.FAULT
    assert (rig.ctl.reason or "").startswith("pretension stopped before the reels were still")
    assert not rig.ctl.homed and not rig.driver.torque_mode
    rig.tick(3)
    held = [r.position_rev for r in rig.driver.readings]
    assert rig.driver.commands[-1] == pytest.approx(held, abs=1e-9)  # holding the turns
