"""Simulated ODrive axes carrying a physical plant: torques by Get_Torques, slack, statics."""

from __future__ import annotations

import math
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest

from controller.core.statics import CableStatics
from controller.service.config import RobotConfig, paper_robot_data, parse_config
from controller.service.simulated import sim_bank, start_sim_bank
from drivers.bus import open_bus
from drivers.odrive import cansimple as cs
from drivers.odrive.driver import ODriveReels
from drivers.odrive.sim import SimODriveAxis, SimODriveBank, SimStats, run_sim, step_axes

DT = 0.001


def physical_config(channel: str = "t", **sim: Any) -> RobotConfig:
    data = paper_robot_data("t")
    data["bus"]["channel"] = channel
    # The tests wait for the effector to come to rest: every mode damped critically, the
    # effector's drag 1/s (a real rope rings for seconds: `[sim] cable_damping_ratio` 0.02).
    data["sim"] = {
        "enabled": True,
        "plant": "physical",
        "cable_damping_ratio": 1.0,
        "effector_damping_n_s_per_m": 5.0,
        **sim,
    }
    return parse_config(data, "test")


# --- one axis: torque reporting ---------------------------------------------------------------


def test_axis_reports_the_load_torque_in_closed_loop_and_zero_when_idle() -> None:
    axis = SimODriveAxis(1, torque_period_s=0.01, encoder_period_s=0.01)
    axis.set_load_torque(-0.75)
    frames = [cs.decode(*f) for _ in range(1000) for f in axis.step(DT)]
    torques = [m for m in frames if isinstance(m, cs.Torques)]
    assert 99 <= len(torques) <= 101  # every 10 ms
    assert {(m.torque_target_nm, m.torque_estimate_nm) for m in torques} == {(0.0, 0.0)}  # IDLE
    axis.handle(cs.SetAxisState(1, cs.AxisState.CLOSED_LOOP_CONTROL))
    (reply,) = axis.handle(cs.RemoteRequest(1, cs.GET_TORQUES))
    assert cs.decode(*reply) == cs.Torques(1, -0.75, -0.75)
    axis.set_load_torque(math.nan)  # ignored: never reported
    assert axis.torque_estimate_nm == -0.75


def test_axis_without_torque_period_answers_only_by_rtr() -> None:
    axis = SimODriveAxis(2)
    frames = [cs.decode(*f) for _ in range(500) for f in axis.step(DT)]
    assert not [m for m in frames if isinstance(m, cs.Torques)]
    (reply,) = axis.handle(cs.RemoteRequest(2, cs.GET_TORQUES))
    assert cs.decode(*reply) == cs.Torques(2, 0.0, 0.0)
    with pytest.raises(ValueError, match="torque_period_s"):
        SimODriveAxis(0, torque_period_s=-1.0)


def test_kinematic_config_builds_no_plant_and_no_torque_broadcast() -> None:
    data = paper_robot_data("t")
    cfg = parse_config(data, "test")
    assert cfg.sim.plant == "kinematic"
    bus = can.Bus(interface="virtual", channel=f"test-plant-{uuid.uuid4().hex}")
    try:
        bank = sim_bank(cfg, bus)
        assert bank.coupling is None
        assert {a.torque_period_s for a in bank.axes} == {0.0}
        physical = sim_bank(physical_config(torque_period_s=0.02), bus)
        assert physical.coupling is not None
        assert {a.torque_period_s for a in physical.axes} == {0.02}
        # a load is given before the bank serves, not after
        physical.start()
        with pytest.raises(RuntimeError, match="already started"):
            physical.carry(physical.coupling)
        assert physical.stop()
    finally:
        bus.shutdown()


def test_physical_plant_needs_a_payload_and_a_power_up_pose() -> None:
    data = paper_robot_data("t")
    data["sim"] = {"plant": "physical"}
    del data["homing"]["power_up_position_m"]
    del data["payload"]
    for k in ("min_tension_n", "max_tension_n", "tension_margin_n"):
        del data["limits"][k]
    with pytest.raises(ValueError) as info:
        parse_config(data, "robot.toml")
    msg = str(info.value)
    assert 'sim.plant: "physical" needs [payload] mass_kg' in msg, msg
    assert 'sim.plant: "physical" needs homing.power_up_position_m' in msg, msg
    data = paper_robot_data("t")
    data["sim"] = {"plant": "physical"}
    data["drive"] = {"kind": "cia402"}
    for r in data["reels"]:
        r["node_id"] += 1  # CANopen node ids start at 1
    with pytest.raises(ValueError, match='"physical" needs simulated ODrives'):
        parse_config(data, "robot.toml")
    data = paper_robot_data("t")
    data["sim"] = {"plant": "elastic", "cable_ea_n": 0.0}
    with pytest.raises(ValueError) as info:
        parse_config(data, "robot.toml")
    msg = str(info.value)
    assert "sim.plant: must be one of kinematic, physical, got 'elastic'" in msg, msg
    assert "sim.cable_ea_n: must be > 0" in msg, msg


class _Exploding:
    positions_rev: tuple[float, ...] = ()

    def step(
        self, positions_rev: Any, dt_s: float, pulls_nm: Any = None, max_speeds_rps: Any = None
    ) -> list[float]:
        raise ValueError("the effector is on anchor 1")


def test_a_failing_coupling_is_counted_and_the_axes_keep_serving() -> None:
    channel = f"test-plant-{uuid.uuid4().hex}"
    bus = can.Bus(interface="virtual", channel=channel)
    stats = SimStats()
    import threading

    stop = threading.Event()
    timer = threading.Timer(0.2, stop.set)
    timer.start()
    try:
        run_sim(bus, [SimODriveAxis(0)], stop, coupling=_Exploding(), stats=stats)
    finally:
        timer.cancel()
        bus.shutdown()
    assert stats.ticks > 50 and stats.coupling_errors == stats.ticks
    assert stats.last_coupling_error == "ValueError: the effector is on anchor 1"
    assert stats.real_time_factor > 1.0


# --- the bank on a virtual bus: the robot hanging on four reels ---------------------------------


@pytest.fixture
def hanging() -> Iterator[tuple[RobotConfig, SimODriveBank, ODriveReels, can.BusABC]]:
    channel = f"test-plant-{uuid.uuid4().hex}"
    # the axes' watchdog is fed by the test's own thread (`hold`), which shares the GIL with the
    # simulation thread: on a loaded host it can be starved for longer than the default 0.3 s
    cfg = physical_config(
        channel, torque_period_s=0.005, encoder_period_s=0.002, watchdog_timeout_s=2.0
    )
    sim_bus = open_bus("virtual", channel)
    drv_bus = open_bus("virtual", channel)
    listen = open_bus("virtual", channel)
    bank = start_sim_bank(cfg, sim_bus)
    driver = ODriveReels(drv_bus, cfg.node_ids)
    yield cfg, bank, driver, listen
    assert bank.stop(timeout_s=2.0)
    for b in (sim_bus, drv_bus, listen):
        b.shutdown()


def wait_for(cond: Callable[[], bool], feed: Callable[[], None], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        feed()
        if cond():
            return True
        time.sleep(0.01)
    return False


def keep(feed: Callable[[], None], seconds: float) -> None:
    """Call `feed` every 10 ms for `seconds`."""
    wait_for(lambda: False, feed, seconds)


def latest_torques(listen: can.BusABC, nodes: tuple[int, ...]) -> dict[int, cs.Torques]:
    """Drain the listening bus; the newest Get_Torques per node."""
    out: dict[int, cs.Torques] = {}
    while (msg := listen.recv(0.0)) is not None:
        m = cs.decode(msg.arbitration_id, msg.data, msg.is_remote_frame)
        if isinstance(m, cs.Torques) and m.node_id in nodes:
            out[m.node_id] = m
    return out


def test_hold_then_pay_one_cable_out_5cm_a_cable_goes_slack_and_three_match_statics(
    hanging: tuple[RobotConfig, SimODriveBank, ODriveReels, can.BusABC],
) -> None:
    cfg, bank, driver, listen = hanging
    readings = driver.read()
    plant = bank.coupling
    assert plant is not None
    reels = [r.reel for r in cfg.reels]

    def poll() -> None:
        driver.poll()

    assert wait_for(lambda: all(r.stamp_ns for r in readings), poll, 5.0)
    start = [r.position_rev for r in readings]
    driver.arm()
    assert wait_for(lambda: all(r.axis_state == 8 for r in readings), poll, 5.0)
    target = list(start)

    def hold() -> None:  # feed the axes' watchdog with the set-points
        driver.poll()
        driver.command(target)

    # holding at the power-up pose: each motor reports the torque of 104.44 N (statics)
    latest_torques(listen, cfg.node_ids)
    keep(hold, 0.3)
    torques = latest_torques(listen, cfg.node_ids)
    assert set(torques) == set(cfg.node_ids)
    held = [
        reels[i].tension_n(start[i], torques[n].torque_estimate_nm)
        for i, n in enumerate(cfg.node_ids)
    ]
    assert held == pytest.approx([104.4422] * 4, rel=1e-4)
    # torque sign: the holding torque winds the cable in (negative on these reels)
    assert all(torques[n].torque_estimate_nm < 0.0 for n in cfg.node_ids)

    # pay cable 1 out by 5 cm: 1 motor turn at 0.05 m per turn
    target[0] = reels[0].position_rev(reels[0].length_m(start[0]) + 0.05)
    assert target[0] == pytest.approx(start[0] + 1.0)
    assert wait_for(lambda: abs(readings[0].position_rev - target[0]) < 1e-6, hold, 5.0)
    # the paper robot's vertical mode settles in about 10 s of simulated time; a loaded machine
    # runs the simulator slower than real time
    # still to 2e-5 m/s: at the 1.7 Hz vertical mode that leaves ~2 um of swing, ~0.04 N of
    # tension on these cables (2e-4 m/s left ~0.4 N, the size of the tolerance below)
    # still for half a period of that mode, not at one turning point of a swing (a loaded
    # machine samples the velocity seldom)
    still_since = [math.inf]

    def still() -> bool:
        now = time.monotonic()
        if math.hypot(*plant.plant.velocity_mps) >= 2e-5:
            still_since[0] = math.inf
        still_since[0] = min(still_since[0], now)
        return now - still_since[0] >= 0.3

    assert wait_for(still, hold, 120.0)
    latest_torques(listen, cfg.node_ids)
    keep(hold, 0.05)
    torques = latest_torques(listen, cfg.node_ids)
    pos = [r.position_rev for r in readings]
    tensions = [
        reels[i].tension_n(pos[i], torques[n].torque_estimate_nm)
        for i, n in enumerate(cfg.node_ids)
    ]
    # at the centre the effector swings onto the 2-4 diagonal: cable 1 slack (0 N)
    assert tensions[0] == 0.0
    taut = [1, 2, 3]
    p = plant.position_m
    three = CableStatics([cfg.anchors_m[i] for i in taut], 0.0, 1e9).solve(p, 5.0)
    assert [tensions[i] for i in taut] == pytest.approx(three.tensions_n, rel=2e-3, abs=0.05)
    assert bank.stats.coupling_errors == 0
    # the encoders report the motor positions, not the cables' stretch
    assert pos == pytest.approx(target, abs=1e-6)


def test_driver_reads_get_torques_cyclic_and_asks_by_rtr() -> None:
    channel = f"test-plant-{uuid.uuid4().hex}"
    node_bus = open_bus("virtual", channel)
    drv_bus = open_bus("virtual", channel)
    clock = [100.0]
    try:
        driver = ODriveReels(
            drv_bus, [3, 4], torque_rtr=True, torque_rtr_period_s=0.5, clock=lambda: clock[0]
        )
        reading = driver.reading(3)
        assert reading.torque_stamp_s == -math.inf
        for frame in (cs.encode_torques(3, -0.5, -0.25), cs.encode_torques(9, 1.0, 1.0)):
            arb, data, _ = frame
            node_bus.send(can.Message(arbitration_id=arb, data=data, is_extended_id=False))
        deadline = time.monotonic() + 2.0
        while reading.torque_stamp_s == -math.inf and time.monotonic() < deadline:
            driver.poll()
        assert reading.torque_nm == -0.25  # the estimate, not the target
        assert reading.torque_stamp_s <= 100.0
        assert driver.stats.errors_by_kind.get("unknown_node") == 1
        snap = reading.snapshot()
        assert (snap.torque_nm, snap.torque_stamp_s) == (reading.torque_nm, reading.torque_stamp_s)
        # RTR: one request per axis per period
        rtrs = []
        while (m := node_bus.recv(0.2)) is not None:
            if m.is_remote_frame:
                rtrs.append(cs.split_id(m.arbitration_id))
        assert sorted(rtrs) == [(3, cs.GET_TORQUES), (4, cs.GET_TORQUES)]
        driver.poll()  # within the period: no new request
        assert node_bus.recv(0.1) is None
        clock[0] += 0.5
        driver.poll()
        assert node_bus.recv(0.5) is not None
    finally:
        node_bus.shutdown()
        drv_bus.shutdown()


# --- torque mode: the pre-tension before homing -------------------------------------------------


def test_pretension_in_torque_mode_takes_up_a_slipped_cable_and_restores_the_statics() -> None:
    """Cable 1 slipped 5 cm off its drum (slack); every reel then pulls in torque control with
    the torque of its statics tension at the power-up pose (recomputed at the reel's turns every
    tick, as the loop does) until the effector is still. Stepped as the bank steps them (no
    bus): the axes advance, the plant takes the torques and turns the reels, 1 ms a tick."""
    from controller.core.plant import ReelPlant
    from controller.service.config import tension_check
    from controller.service.simulated import sim_plant
    from tests.fakes import make_config, power_up_turns

    cfg = make_config(
        sim=dict(plant="physical", cable_damping_ratio=1.0, effector_damping_n_s_per_m=5.0)
    )
    turns = power_up_turns(cfg)
    plant = sim_plant(cfg, turns)
    assert isinstance(plant, ReelPlant)
    pose = tuple(float(v) for v in cfg.homing.power_up_position_m)
    statics = tension_check(cfg.payload, cfg.tension, cfg.geometry).solve(pose).tensions_n
    reels = [r.reel for r in cfg.reels]
    axes = [
        SimODriveAxis(
            n,
            initial_position_rev=p,
            max_velocity_rps=cfg.sim.max_velocity_rps,
            max_accel_rps2=cfg.sim.max_accel_rps2,
        )
        for n, p in zip(cfg.node_ids, turns, strict=True)
    ]
    for a in axes:
        a.coupled = True
    plant.slip(0, 0.05)

    def tick() -> None:
        step_axes(axes, plant, DT)

    tick()
    assert plant.tensions_n[0] == 0.0  # slack
    for a in axes:  # the driver's enter_torque_mode
        a.handle(cs.SetInputTorque(a.node_id, 0.0))
        a.handle(cs.SetControllerMode(a.node_id, cs.ControlMode.TORQUE_CONTROL, 1))
        a.handle(cs.SetAxisState(a.node_id, cs.AxisState.CLOSED_LOOP_CONTROL))
    # a drive that turns no faster than 0.05 m/s of cable (Set_Limits): 1 rev/s here
    for a in axes:
        a.handle(cs.SetLimits(a.node_id, 1.0, 10.0))
    still = ticks = 0
    while ticks < round(60.0 / DT):
        for a, reel, t in zip(axes, reels, statics, strict=True):
            a.handle(cs.SetInputTorque(a.node_id, reel.torque_nm(a.position_rev, t)))
        tick()
        ticks += 1
        assert max(abs(a.velocity_rps) for a in axes) <= 1.0 + 1e-9
        if math.hypot(*plant.plant.velocity_mps) < 1e-4:
            still += 1
            if still >= 1000:
                break
        else:
            still = 0
    print(f"pre-tension: effector still after {ticks * DT:.1f} simulated s")
    assert still >= 1000, "the effector did not come to rest within 60 simulated seconds"
    assert plant.tensions_n == pytest.approx(statics, rel=1e-3)
    offset_m = [p - q for p, q in zip(plant.position_m, pose, strict=True)]
    print(f"pre-tension: effector offset {[round(1000 * d, 3) for d in offset_m]} mm")
    assert math.dist(plant.position_m, pose) < 1e-3
    # the encoders tell: cable 1 was wound in by the 5 cm it slipped
    wound_m = reels[0].length_m(axes[0].position_rev) - reels[0].length_m(turns[0])
    assert wound_m == pytest.approx(-0.05, abs=1e-3)
