"""The pre-tension in real time against simulated ODrives carrying the payload (physical
plant): cables that slipped while the robot was disarmed are taken up in torque control, and
the home pose is declared where the effector really is; then the robot moves as usual."""

from __future__ import annotations

import math
import re
from collections.abc import Iterator

import pytest

from controller.core import kinematics
from controller.core.commands import Arm, Move, Pretension, Reset
from controller.core.plant import equilibrium, unstretched_lengths
from controller.core.states import State
from controller.service.config import tension_check
from tests.fakes import make_config
from tests.service.test_loop_sim_statics import PhysicalRig

# Stillness to 0.2 mm/s of cable for 3 s: the effector's vertical bounce on the paper robot's
# long flat cables (period about 5 s) shows in the cables at an eighth of it.
HOMING = {"pretension_still_mps": 0.0002, "pretension_settle_s": 3.0, "pretension_timeout_s": 60.0}


@pytest.fixture
def rig() -> Iterator[PhysicalRig]:
    r = PhysicalRig("cyclic", HOMING)
    yield r
    r.close()


@pytest.fixture
def limited_rig() -> Iterator[PhysicalRig]:
    """The rig with the drives' configured limits known (the simulated drives' own vel_limit
    and a current limit), so the pre-tension winds at `pretension_speed_mps`: at the drives'
    5 m/s of cable, 20 cm of slack taken up yanks the effector into a swing that moved a cable
    0.46 m of the 0.5 m travel limit on the plant alone, past it after a stall of a loaded host."""
    r = PhysicalRig("cyclic", HOMING, drive_limits=(make_config().sim.max_velocity_rps, 40.0))
    yield r
    r.close()


def test_slipped_cables_are_taken_up_and_the_home_is_declared_where_the_effector_is(
    limited_rig: PhysicalRig,
) -> None:
    rig = limited_rig
    home = tuple(float(v) for v in rig.cfg.homing.power_up_position_m)
    rig.wait(lambda: rig.ctl.pose_valid, 3.0, "a valid pose")
    plant = rig.bank.coupling
    statics = tension_check(rig.cfg.payload, rig.cfg.tension, rig.cfg.geometry)
    want = statics.solve(home).tensions_n
    # Disarmed (the reels braked), cables 2 and 4 slip 20 and 10 cm off their drums: the
    # effector drops onto the others, and the encoders see nothing. (A few centimetres would
    # not do: the effector's drop on elastic cables takes up that much, all four stay taut.)
    plant.slip(1, 0.20)
    plant.slip(3, 0.10)
    rig.wait(
        lambda: (
            math.dist(plant.position_m, home) > 0.01
            and math.hypot(*plant.plant.velocity_mps) < 0.01
            and min(plant.tensions_n) < 1.0
        ),
        10.0,
        "the effector fallen onto the other cables, a slack one",
    )
    assert rig.ctl.pose_m is not None and math.dist(rig.ctl.pose_m, home) < 1e-6
    print(f"after the slips the effector is at {plant.position_m}, tensions {plant.tensions_n}")

    reply = rig.ctl.submit(Pretension(home)).result(timeout=2.0)
    assert reply["tensions_n"] == pytest.approx(want, rel=1e-9)
    assert reply["speed_limited"] is True
    assert rig.ctl.state is State.PRETENSIONING
    took = rig.wait(lambda: rig.ctl.state is not State.PRETENSIONING, 60.0, "the pre-tension")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    assert rig.ctl.home_source == "pretension"
    result = rig.ctl.status()["pretension"]["result"]
    assert result["ok"] is True
    # the slipped cables were wound in and the effector drawn back to the home pose
    assert math.dist(plant.position_m, home) < 0.002, plant.position_m
    assert list(plant.tensions_n) == pytest.approx(want, rel=0.02)
    rig.wait(lambda: rig.ctl.pose_valid, 1.0, "a valid pose")
    assert rig.ctl.pose_m is not None and math.dist(rig.ctl.pose_m, home) < 0.002
    assert rig.ctl.residual_m is not None and rig.ctl.residual_m < 0.002
    print(f"pre-tension: still after {result['still_after_s']:.2f} s ({took:.2f} s wall)")

    # and the robot moves as usual: the cables stay taut, no slack fault
    target = (home[0] + 1.0, home[1] + 0.5, home[2] + 0.3)
    rig.ctl.submit(Move(target, speed_mps=0.5)).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.state is State.MOVING, 1.0, "MOVING")
    rig.wait(lambda: rig.ctl.state is not State.MOVING, 15.0, "the end of the move")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    # The controller's cables are rigid (no reel cable_ea_n), the plant's stretch under the
    # move's tensions: on these long flat cables (sin 7 degrees) a millimetre or two of stretch
    # leaves the effector about 12 mm below the target at rest. The slips are fully accounted
    # for when it rests where a rigid controller puts it on intact cables: the plant's rest
    # pose for the rigid lengths of the target less the stretch the home was declared with.
    params = plant.plant.params
    home_stretch_m = [
        length - unstretched
        for length, unstretched in zip(
            kinematics.ipk_point(rig.cfg.geometry, home),
            unstretched_lengths(params, home, want),
            strict=True,
        )
    ]
    rest = equilibrium(
        params,
        [
            length - stretch
            for length, stretch in zip(
                kinematics.ipk_point(rig.cfg.geometry, target), home_stretch_m, strict=True
            )
        ],
        target,
    ).position_m
    assert 0.005 < math.dist(rest, target) < 0.02, rest
    rig.wait(
        lambda: (
            math.hypot(*plant.plant.velocity_mps) < 1e-4
            and math.dist(plant.position_m, rest) < 5e-4
        ),
        10.0,
        "the effector at rest where the rigid model's lengths put it",
    )
    assert rig.ctl.pose_m is not None and math.dist(rig.ctl.pose_m, target) < 0.001
    planned = rig.ctl.status()["tensions"]["planned_n"]
    rig.wait(
        lambda: list(plant.tensions_n) == pytest.approx(planned, rel=0.05),
        5.0,
        "the tensions of the plan",
    )


def test_a_reel_with_nothing_on_it_winds_until_the_travel_limit_faults(
    rig: PhysicalRig,
) -> None:
    home = tuple(float(v) for v in rig.cfg.homing.power_up_position_m)
    rig.wait(lambda: rig.ctl.pose_valid, 3.0, "a valid pose")
    plant = rig.bank.coupling
    plant.slip(2, 5.0)  # cable 3 is off its drum: its reel turns and nothing pulls back
    rig.ctl.submit(Pretension(home)).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.state is not State.PRETENSIONING, 60.0, "the end of the pre-tension")
    assert rig.ctl.state is State.FAULT
    reason = rig.ctl.reason or ""
    found = re.match(r"pretension: cable 3 moved ([0-9.]+) m without coming still", reason)
    assert found, reason
    # checked every tick: past the limit by at most what the free reel winds (at the drive's
    # speed limit) in the longest gap between ticks the loop measured (a loaded host stalls it)
    loop = rig.ctl.status()["loop"]
    gap_s = 2.0 / loop["rate_hz"] + loop["jitter_max_s"] + loop["compute_max_s"]
    reel = rig.cfg.reels[2].reel
    fastest_mps = rig.cfg.sim.max_velocity_rps * abs(reel.length_m(1.0) - reel.length_m(0.0))
    limit_m = rig.cfg.homing.pretension_max_travel_m
    assert limit_m <= float(found.group(1)) <= limit_m + fastest_mps * gap_s + 0.01, (reason, loop)
    # the drives hold where the reels are, in position control
    axes = [rig.bank.axis(n) for n in rig.ctl.node_ids]
    rig.wait(lambda: all(a.control_mode == 3 for a in axes), 1.0, "position control on every axis")


def test_a_pretension_right_after_an_estop_and_reset_is_judged_on_the_drives_new_answers(
    rig: PhysicalRig,
) -> None:
    # After an incident is exactly when a user pre-tensions: the drives still report the
    # e-stop's error until they take the Clear_Errors of the pre-tension. Readings from before
    # that command must not fault it.
    home = tuple(float(v) for v in rig.cfg.homing.power_up_position_m)
    rig.wait(lambda: rig.ctl.pose_valid, 3.0, "a valid pose")
    rig.ctl.submit(Arm()).result(timeout=2.0)
    rig.wait(lambda: rig.ctl.state is State.HOLDING, 5.0, "HOLDING")
    rig.ctl.request_estop()
    rig.wait(lambda: rig.ctl.state is State.ESTOPPED, 2.0, "ESTOPPED")
    rig.wait(
        lambda: all(r.fault is not None and not r.ready for r in rig.driver.read()),
        2.0,
        "every axis reporting the e-stop",
    )
    rig.ctl.submit(Reset()).result(timeout=2.0)
    assert rig.ctl.state is State.DISARMED
    reply = rig.ctl.submit(Pretension(home)).result(timeout=2.0)
    assert reply["ok"] is True
    rig.wait(lambda: rig.ctl.state is not State.PRETENSIONING, 60.0, "the end of the pre-tension")
    assert rig.ctl.state is State.HOLDING, rig.ctl.reason
    assert rig.ctl.status()["pretension"]["result"]["ok"] is True
