"""Cable sag through the control loop: the loop in real time against simulated ODrives carrying
the payload on heavy elastic cables (the physical plant's catenaries), the controller's reels
configured with the cables' EA and mass per metre. After a move and settling, the plant's true
effector position is within a millimetre of the target and the published pose within a
millimetre of the truth on the paper robot; poses the cables cannot hold with their weight are
refused with the reason."""

from __future__ import annotations

import uuid
from dataclasses import replace
from typing import Any

import pytest

from controller.core.commands import CommandRefused, Move
from controller.core.states import State
from controller.service.config import RobotConfig
from tests.service.test_loop_sim_stretch import StretchRig, paper_config

EA_N = 4.5e5
DYNEEMA = 0.0083
STEEL = 0.036
Vec3 = tuple[float, float, float]


def sag_config(
    plant_mass_kg_per_m: float,
    model_mass_kg_per_m: float | None,
    payload_kg: float = 5.0,
    **kw: Any,
) -> RobotConfig:
    """The paper robot (EA 4.5e5 N in the plant and the controller) whose simulated cables weigh
    `plant_mass_kg_per_m` and whose reels say `model_mass_kg_per_m` (None: massless). The
    heavy plant and plans cost the process's threads more than stretch does: on a loaded
    two-core host the simulator thread has been starved for 4 s, so the staleness faults and
    the simulated watchdog get more room than the stretch rig's."""
    cfg = paper_config(EA_N, EA_N, f"test-sag-{uuid.uuid4().hex[:8]}", **kw)
    return replace(
        cfg,
        reels=tuple(replace(r, cable_mass_kg_per_m=model_mass_kg_per_m) for r in cfg.reels),
        sim=replace(
            cfg.sim,
            cable_mass_kg_per_m=plant_mass_kg_per_m,
            watchdog_timeout_s=10.0,
            effector_damping_n_s_per_m=payload_kg,  # 1 s^-1 times the mass, as the stretch rig's
        ),
        faults=replace(cfg.faults, stale_timeout_s=8.0, heartbeat_timeout_s=8.0),
        payload=replace(cfg.payload, mass_kg=payload_kg),
    )


@pytest.mark.timeout(400)  # three moves of up to 40 m at 2 m/s, each settling to 20 um/s
@pytest.mark.parametrize(
    ("per_m", "payload_kg", "targets"),
    [
        (STEEL, 5.0, [(20.0, 10.0, 2.0), (35.0, 20.0, 3.0), (10.0, -5.0, 0.5)]),
        (DYNEEMA, 20.0, [(20.0, 10.0, 2.0), (35.0, 20.0, 3.0), (10.0, -5.0, 0.5)]),
    ],
)
def test_paper_robot_with_sag_is_within_a_millimetre(
    per_m: float, payload_kg: float, targets: list[Vec3]
) -> None:
    rig = StretchRig(sag_config(per_m, per_m, payload_kg))
    try:
        assert rig.ctl.cables.sag is not None
        rig.arm()
        for target in targets:
            err_target, err_pose = rig.move_and_settle(target)
            assert rig.ctl.state is State.HOLDING, rig.ctl.reason
            assert err_target < 1e-3, (target, err_target)
            assert err_pose < 1e-3, (target, err_pose)
        # the published tensions are the ones the reels carry: the plant's, at rest
        planned = rig.ctl.planned_tensions_n
        assert planned == pytest.approx(rig.plant.tensions_n, rel=1e-3)
    finally:
        rig.close()


def test_paper_robot_without_the_sag_model_misses_by_decimetres() -> None:
    """The same rig with massless cables in the controller (today's kinematics with stretch):
    3 mm steel at 5 kg puts the effector 0.7 m off at (35, 20, 3) m, and the published pose
    (which sits on the set-point) as far off the truth."""
    rig = StretchRig(sag_config(STEEL, None))
    try:
        assert rig.ctl.cables.sag is None
        rig.arm()
        err_target, err_pose = rig.move_and_settle((35.0, 20.0, 3.0))
        assert err_target > 0.3
        assert err_pose > 0.3
    finally:
        rig.close()


def test_a_pose_the_cables_cannot_hold_with_their_weight_is_refused() -> None:
    """(0, 0, 6) m with 3 mm steel at 5 kg: 607 N at the anchors (the straight cables' rule
    allows it: 360 N); the move is refused with the cable, its end and the limit."""
    rig = StretchRig(sag_config(STEEL, STEEL))
    try:
        rig.arm()
        with pytest.raises(CommandRefused, match="at the anchor above 495 N") as info:
            rig.ctl.submit(Move((0.0, 0.0, 6.0))).result(timeout=5.0)
        assert "cables' weight" in str(info.value)
        assert rig.ctl.state is State.HOLDING
    finally:
        rig.close()
