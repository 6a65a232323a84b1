"""`cablebot resonance`: the effector's modes measured from the torque telemetry after an
excitation, on the simulated physical plant through the real control step (the plant is the
truth), and the refusals."""

from __future__ import annotations

import math

import pytest

from controller.cli.bench.vibration import (
    PAPER_EA_N,
    PlantRig,
    RecordingPublisher,
    RigLink,
    robot_config,
    robot_data,
)
from controller.cli.resonance import format_report, measure, ringing
from controller.cli.session import Refused
from controller.core.commands import Disarm
from controller.core.vibration import effector_modes
from controller.service.simulated import sim_plant_params


def rig(
    model_ea_n: float,
    telemetry: str = "cyclic",
    start_m: tuple[float, float, float] = (0.0, 0.0, 2.0),
) -> tuple[PlantRig, RigLink]:
    cfg = robot_config(
        robot_data("paper"),
        mass_kg=5.0,
        plant_ea_n=PAPER_EA_N,
        model_ea_n=model_ea_n,
        start_m=start_m,
        shaper={"type": "2hump_ei"},
        telemetry=telemetry,
    )
    poses = RecordingPublisher()
    r = PlantRig(cfg, poses)
    return r, RigLink(r, poses)


def test_resonance_finds_the_plants_modes_and_the_models_error() -> None:
    # The controller's model of the cables is 20 % too stiff: its frequencies 9.5 % high.
    target = (12.0, -6.0, 3.0)
    r, link = rig(1.2 * PAPER_EA_N, start_m=target)  # already there: no long move first
    rep = measure(link, list(target), seconds=6.0)
    cfg = r.cfg
    plant = sim_plant_params(cfg)
    tensions = r.ctl.status()["tensions"]["planned_n"]
    truth = effector_modes(
        cfg.anchors_m,
        target,
        tensions,
        list(plant.ea_n),
        5.0,
        cable_damping_ratio=plant.cable_damping_ratio,
        effector_damping_n_s_per_m=plant.effector_damping_n_s_per_m,
    )
    for got, want in zip(rep["frequencies_hz"], truth.frequencies_hz, strict=True):
        assert got == pytest.approx(want, rel=0.05)
    for got, want in zip(rep["damping_ratios"], truth.damping_ratios, strict=True):
        assert got == pytest.approx(want, rel=0.30)
    assert rep["model_frequencies_hz"] is not None
    assert rep["frequency_scale"] == pytest.approx(math.sqrt(1.0 / 1.2), rel=0.03)
    assert rep["shaper"]["frequency_scale"] == pytest.approx(rep["frequency_scale"], abs=1e-4)
    # the robot is back where it was asked, shaping on again as configured
    st = r.ctl.status()
    assert st["state"] == "HOLDING"
    assert st["setpoint_m"] == pytest.approx(list(target), abs=1e-9)
    assert st["shaper"]["type"] == "2hump_ei"
    text = format_report(rep)
    assert "[shaper]" in text and 'type = "2hump_ei"' in text and "frequency_scale = " in text


def test_resonance_is_refused_while_not_holding_outside_the_workspace_or_without_telemetry() -> (
    None
):
    r, link = rig(PAPER_EA_N)
    with pytest.raises(Refused, match=r"refused|outside|above|z="):
        measure(link, [0.0, 0.0, 90.0])
    assert r.ctl.status()["state"] == "HOLDING"  # nothing moved
    assert r.ctl.setpoint_m == (0.0, 0.0, 2.0)
    fut = r.ctl.submit(Disarm())
    r.tick(2)
    assert fut.done()
    with pytest.raises(Refused, match="needs the robot HOLDING still, it is DISARMED"):
        measure(link, [0.0, 0.0, 2.0])
    _, quiet = rig(PAPER_EA_N, telemetry="off")
    with pytest.raises(Refused, match="torque telemetry"):
        measure(quiet, [1.0, 0.0, 2.0])


def test_ringing_keeps_new_readings_after_the_motion() -> None:
    samples = [
        {"state": "HOLDING", "stamp_ns": 1, "measured_tensions_n": [1.0, 1.0]},
        {"state": "MOVING", "stamp_ns": 2, "measured_tensions_n": [2.0, 1.0]},
        {"state": "HOLDING", "stamp_ns": 3_000_000_000, "measured_tensions_n": [3.0, 1.0]},
        {"state": "HOLDING", "stamp_ns": 3_002_000_000, "measured_tensions_n": [3.0, 1.0]},
        {"state": "HOLDING", "stamp_ns": 3_004_000_000, "measured_tensions_n": [3.5, None]},
        {"state": "HOLDING", "stamp_ns": 3_006_000_000, "measured_tensions_n": [3.5, 1.5]},
    ]
    times, tensions = ringing(samples)
    assert times == pytest.approx([3.0, 3.006])
    assert tensions == [[3.0, 1.0], [3.5, 1.5]]
