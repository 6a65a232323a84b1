"""`cablebot sim --config FILE`: the robot's simulated ODrive nodes as their own process.

The axes are those of the config's reels, on the config's bus, initialised at the configured
power-up pose (motor turns = reel.position_rev(ipk(power-up pose)) with the config's reel
offsets), with the `[sim]` section's speed, acceleration, broadcast periods and axis watchdog
(`watchdog_timeout_s`, on by default: a crashed daemon leaves the axes IDLE, not running). With
`[sim] plant = "physical"` the axes carry the payload on elastic cables (`sim_plant`) and
report the torque their cables need by Get_Torques. Prints "READY <node ids>" on stdout once
serving; runs until SIGTERM/SIGINT (exit 0), then logs how fast it ran (ticks, late ticks,
real-time factor).
`start_sim_bank` is the same thing as a thread, used by `cablebot run` when `[sim] enabled`.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from pathlib import Path
from types import FrameType
from typing import Any

log = logging.getLogger("cablebot.sim")


def sim_axes(cfg: Any) -> list[Any]:
    """Simulated axes for the config's reels at the power-up pose (all at 0 turns without one).

    Raises kinematics.KinematicsError / ValueError if the power-up pose is unusable.
    """
    from controller.core import kinematics
    from drivers.odrive.sim import SimODriveAxis

    pose = cfg.homing.power_up_position_m
    if pose is not None:
        lengths = kinematics.ipk_point(cfg.geometry, tuple(float(v) for v in pose))
        turns = [r.reel.position_rev(L) for r, L in zip(cfg.reels, lengths, strict=True)]
    else:
        turns = [0.0] * len(cfg.reels)
    s = cfg.sim
    return [
        SimODriveAxis(
            int(r.node_id),
            initial_position_rev=t,
            max_velocity_rps=float(s.max_velocity_rps),
            max_accel_rps2=float(s.max_accel_rps2),
            encoder_period_s=float(s.encoder_period_s),
            heartbeat_period_s=float(s.heartbeat_period_s),
            watchdog_timeout_s=float(getattr(s, "watchdog_timeout_s", 0.0)),
            torque_period_s=float(s.torque_period_s) if s.plant == "physical" else 0.0,
        )
        for r, t in zip(cfg.reels, turns, strict=True)
    ]


def sim_plant(cfg: Any, axes: Any) -> Any:
    """The `ReelPlant` the axes carry with `[sim] plant = "physical"` (None for "kinematic").

    The effector starts at rest at the power-up pose, its cables holding the payload with the
    statics distribution farthest from the tension limits, with the axes at their initial
    turns. Raises PlantError / EquilibriumError / StaticsError if that pose cannot be held.
    """
    if cfg.sim.plant != "physical":
        return None
    from controller.core.plant import PlantParams, ReelPlant
    from controller.service.config import tension_check

    pose = tuple(float(v) for v in cfg.homing.power_up_position_m)
    tensions = tension_check(cfg.payload, cfg.tension, cfg.geometry).solve(pose).tensions_n
    params = PlantParams(cfg.anchors_m, float(cfg.sim.cable_ea_n), float(cfg.payload.mass_kg))
    return ReelPlant(
        params, [r.reel for r in cfg.reels], pose, [a.position_rev for a in axes], tensions
    )


def start_sim_bank(cfg: Any, bus: Any) -> Any:
    """Start a `SimODriveBank` thread serving `sim_axes(cfg)` on `bus`; returns the bank.

    With the `virtual` interface `bus` must be a bus object of its own on the controller's
    channel (python-can virtual buses do not hear their own frames).
    """
    from drivers.odrive.sim import SimODriveBank

    tick_s = float(getattr(cfg.sim, "tick_s", 0.001))
    axes = sim_axes(cfg)
    return SimODriveBank(bus, axes, tick_s=tick_s, coupling=sim_plant(cfg, axes)).start()


def cmd_sim(args: argparse.Namespace) -> int:
    """Entry point of `cablebot sim`."""
    from controller.service.config import ConfigError, load_config
    from drivers.bus import open_bus
    from drivers.odrive.sim import SimStats, run_sim

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        cfg = load_config(args.config)
    except (ConfigError, OSError) as exc:
        log.error("configuration: %s", exc)
        return 2
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    b = cfg.bus
    axes = sim_axes(cfg)
    try:
        plant = sim_plant(cfg, axes)
    except ValueError as exc:  # PlantError, EquilibriumError, StaticsError
        log.error("physical plant: %s", exc)
        return 2
    stats = SimStats()
    bus = open_bus(b.interface, b.channel, b.bitrate, **dict(b.options))
    try:
        nodes = ",".join(str(a.node_id) for a in axes)
        log.info(
            "simulated ODrive nodes %s on %s %s (%s plant)",
            nodes,
            b.interface,
            b.channel,
            cfg.sim.plant,
        )
        print(f"READY {nodes}", flush=True)
        run_sim(
            bus,
            axes,
            stop,
            tick_s=float(getattr(cfg.sim, "tick_s", 0.001)),
            coupling=plant,
            stats=stats,
        )
    finally:
        bus.shutdown()
    log.info(
        "served %d ticks (%.1f s simulated), %d late, real-time factor %.1f%s",
        stats.ticks,
        stats.simulated_s,
        stats.late_ticks,
        stats.real_time_factor,
        f", {stats.coupling_errors} plant errors (last: {stats.last_coupling_error})"
        if stats.coupling_errors
        else "",
    )
    return 0


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot sim`."""
    p = sub.add_parser(
        "sim",
        help="run the robot's simulated ODrive nodes on its bus (own process)",
        description="Serve simulated ODrive axes for the config's reels until SIGTERM.",
    )
    p.add_argument("--config", type=Path, default=None, help="robot TOML (default: built-in)")
    p.set_defaults(func=cmd_sim)


if __name__ == "__main__":  # pragma: no cover
    from controller.cli import main

    sys.exit(main(["sim", *sys.argv[1:]]))
