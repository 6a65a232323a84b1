"""The simulated drives a robot's configuration asks for, built through the drive registry.

Used by `cablebot run` (in-process, `[sim] enabled`) and by `cablebot sim` (as their own
process). The drives are those of the config's reels, of the config's drive family (`[drive]
kind`), initialised at the configured power-up pose (motor turns =
reel.position_rev(ipk(power-up pose)) with the config's reel offsets), with the `[sim]` section's
speed, acceleration and tick and, where the family uses them, its broadcast periods and axis
watchdog. With `[sim] plant = "physical"` (ODrive) the axes carry the payload on elastic cables
(`sim_plant`; heavy ones hang in catenaries) and report the torque their cables need by
Get_Torques.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

from controller.service.keys import TRUTH

log = logging.getLogger("cablebot.sim")


def initial_turns(cfg: Any) -> tuple[float, ...]:
    """Motor turns of the config's reels at the power-up pose (all 0 without one).

    Raises kinematics.KinematicsError / ValueError if the power-up pose is unusable.
    """
    from controller.core import kinematics

    pose = cfg.homing.power_up_position_m
    if pose is None:
        return (0.0,) * len(cfg.reels)
    lengths = kinematics.ipk_point(cfg.geometry, tuple(float(v) for v in pose))
    return tuple(r.reel.position_rev(L) for r, L in zip(cfg.reels, lengths, strict=True))


def sim_settings(cfg: Any) -> Any:
    """The `drivers.registry.SimSettings` of the config's `[sim]` section and power-up pose."""
    from drivers.registry import SimSettings

    s = cfg.sim
    return SimSettings(
        initial_positions_rev=initial_turns(cfg),
        max_velocity_rps=float(s.max_velocity_rps),
        max_accel_rps2=float(s.max_accel_rps2),
        tick_s=float(getattr(s, "tick_s", 0.001)),
        encoder_period_s=float(s.encoder_period_s),
        heartbeat_period_s=float(s.heartbeat_period_s),
        watchdog_timeout_s=float(getattr(s, "watchdog_timeout_s", 0.0)),
    )


def sim_cable_masses(cfg: Any) -> tuple[float, ...]:
    """The simulated cables' mass per metre (kg/m): `[sim] cable_mass_kg_per_m` for every
    cable, else each reel's `cable_mass_kg_per_m` (0 without one). Raises nothing."""
    m = getattr(cfg.sim, "cable_mass_kg_per_m", None)
    if m is not None:
        return (float(m),) * len(cfg.reels)
    return tuple(float(r.cable_mass_kg_per_m or 0.0) for r in cfg.reels)


def sim_plant(cfg: Any, turns: Sequence[float]) -> Any:
    """The `ReelPlant` the axes carry with `[sim] plant = "physical"` (None for "kinematic").

    The effector starts at rest at the power-up pose, its cables holding the payload with the
    statics distribution farthest from the tension limits (with heavy simulated cables, that
    distribution along their catenaries: `controller.core.sag`), with the motors at `turns`.
    Raises PlantError / EquilibriumError / StaticsError (ValueErrors) if that pose cannot be
    held.
    """
    if cfg.sim.plant != "physical":
        return None
    from controller.core.plant import ReelPlant
    from controller.service.config import tension_check

    pose = tuple(float(v) for v in cfg.homing.power_up_position_m)
    params = sim_plant_params(cfg)
    reels = [r.reel for r in cfg.reels]
    check = tension_check(cfg.payload, cfg.tension, cfg.geometry)
    if not params.sags:
        return ReelPlant(params, reels, pose, turns, check.solve(pose).tensions_n)
    from controller.core.sag import SagStatics
    from controller.core.sag_plant import SagPlant

    ea = [float(cfg.sim.cable_ea_n)] * len(reels)
    sag = SagStatics(check.statics, check.mass_kg, params.cable_weight_n_per_m, ea)
    lengths = sag.solve(pose).paid_out_m  # the catenaries that hold it there, at rest
    return ReelPlant(params, reels, pose, turns, plant=SagPlant(params, pose, lengths))


def sim_plant_params(cfg: Any) -> Any:
    """The `controller.core.plant.PlantParams` of the config's physical plant: the anchors,
    `[sim] cable_ea_n`, the payload's mass, `[sim] cable_damping_ratio` and
    `effector_damping_n_s_per_m` (unset: the plant's light drag), the cables' mass per metre
    (`sim_cable_masses`). Raises PlantError on parameters the plant refuses, AttributeError
    without a payload."""
    from controller.core.plant import PlantParams

    s = cfg.sim
    drag = s.effector_damping_n_s_per_m
    return PlantParams(
        cfg.anchors_m,
        float(s.cable_ea_n),
        float(cfg.payload.mass_kg),
        cable_damping_ratio=float(s.cable_damping_ratio),
        effector_damping_n_s_per_m=None if drag is None else float(drag),
        cable_mass_kg_per_m=sim_cable_masses(cfg),
    )


def sim_bank(cfg: Any, bus: Any) -> Any:
    """The config's simulated drives on `bus` (a `drivers.registry.SimBank`, not started),
    carrying the physical plant when `[sim] plant = "physical"`.

    Raises ValueError / KinematicsError on an unusable power-up pose or settings, ValueError
    when the family's simulated drives cannot carry a load.
    """
    from drivers import registry

    fam = registry.family(cfg.drive.kind)
    settings = sim_settings(cfg)
    bank = fam.sim_bank(bus, cfg.node_ids, cfg.drive.options, settings)
    plant = sim_plant(cfg, settings.initial_positions_rev)
    if plant is not None:
        carry = getattr(bank, "carry", None)
        if carry is None:
            raise ValueError(f"simulated {fam.title} drives cannot carry a physical plant")
        carry(plant, float(cfg.sim.torque_period_s))
    return bank


def start_sim_bank(cfg: Any, bus: Any) -> Any:
    """Start `sim_bank(cfg, bus)` serving in its thread; returns the bank.

    With the `virtual` interface `bus` must be a bus object of its own on the controller's
    channel (python-can virtual buses do not hear their own frames).
    """
    return sim_bank(cfg, bus).start()


def schedule_sim_thread(cfg: Any, thread: Any) -> str:
    """Give the simulated drives' serving `thread` (a started `threading.Thread`) the control
    loop's real-time scheduling, one SCHED_FIFO step below the loop (`loop.rt_priority` - 1),
    when `loop.realtime` is on: the simulated drives stand in for hardware, and a sim starved
    by a busy machine looks like a stale node (`stale_encoder`). Returns what was obtained,
    for the log. Raises nothing."""
    from controller.service.runner import set_realtime

    if not cfg.loop.realtime:
        return "SCHED_OTHER (loop.realtime = false)"
    if thread is None or thread.native_id is None:
        return "SCHED_OTHER (no serving thread)"
    return set_realtime(max(1, int(cfg.loop.rt_priority) - 1), thread.native_id)


TRUTH_KEY = TRUTH
"""Key (under the robot's Zenoh prefix) of the simulator's ground truth: the physical plant's
true effector position and cable tensions, JSON ``{"position_m": [x, y, z], "tensions_n":
[...]}``.  The simulator's key, never the controller's input."""


def truth_payload(plant: Any) -> bytes | None:
    """The `TRUTH_KEY` JSON of a `controller.core.plant.ReelPlant` (None if a value is not
    finite: nothing non-finite is published). Raises nothing."""
    import json
    import math

    try:
        pos = [float(v) for v in plant.position_m]
        ten = [float(v) for v in plant.tensions_n]
    except (TypeError, ValueError, AttributeError):
        return None
    if not all(map(math.isfinite, pos + ten)):
        return None
    return json.dumps({"position_m": pos, "tensions_n": ten}, separators=(",", ":")).encode()


class TruthFeed:
    """A thread that puts the plant's `truth_payload` through `put` every `period_s` (the pose
    rate) until `stop`. `put` failures are counted (`errors`), never raised."""

    def __init__(self, plant: Any, put: Any, period_s: float) -> None:
        import threading

        self.plant = plant
        self.put = put
        self.period_s = max(1e-3, float(period_s))
        self.published = 0
        self.errors = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sim-truth", daemon=True)

    def start(self) -> TruthFeed:
        """Start the thread; returns self."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop and join the thread (idempotent)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)

    def _run(self) -> None:
        import time

        next_s = time.monotonic()
        while not self._stop.is_set():
            data = truth_payload(self.plant)
            if data is not None:
                try:
                    self.put(data)
                    self.published += 1
                except Exception as exc:  # a closing session: keep the simulator running
                    self.errors += 1
                    log.debug("sim truth: %s", exc)
            next_s += self.period_s
            delay = next_s - time.monotonic()
            if delay < 0.0:
                next_s = time.monotonic()
                delay = 0.0
            self._stop.wait(delay)
