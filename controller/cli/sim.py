"""`cablebot sim --config FILE`: the robot's simulated drives as their own process.

The drives are those of the config's reels, of the config's drive family (`[drive] kind`,
built through `drivers.registry`: simulated ODrive axes or simulated CiA 402 drives), on the
config's bus, initialised at the configured power-up pose (motor turns =
reel.position_rev(ipk(power-up pose)) with the config's reel offsets), with the `[sim]`
section's speed, acceleration and tick and, where the family uses them, its broadcast periods
and axis watchdog (ODrive: `watchdog_timeout_s`, on by default: a crashed daemon leaves the
axes IDLE, not running). The family's `[drive]` options apply too (CiA 402: counts per turn,
velocity units, EDS). With `[sim] plant = "physical"` (ODrive) the axes carry the payload on
elastic cables (`sim_plant`) and report the torque their cables need by Get_Torques. Prints
"READY <node ids>" on stdout once serving; runs until SIGTERM/SIGINT (exit 0), then logs how
fast it ran (ticks, late ticks, real-time factor) when the bank counts them. `start_sim_bank`
is the same thing as a thread, used by `cablebot run` when `[sim] enabled`.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from types import FrameType
from typing import Any

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


def sim_plant(cfg: Any, turns: Sequence[float]) -> Any:
    """The `ReelPlant` the axes carry with `[sim] plant = "physical"` (None for "kinematic").

    The effector starts at rest at the power-up pose, its cables holding the payload with the
    statics distribution farthest from the tension limits, with the motors at `turns`. Raises
    PlantError / EquilibriumError / StaticsError (ValueErrors) if that pose cannot be held.
    """
    if cfg.sim.plant != "physical":
        return None
    from controller.core.plant import PlantParams, ReelPlant
    from controller.service.config import tension_check

    pose = tuple(float(v) for v in cfg.homing.power_up_position_m)
    tensions = tension_check(cfg.payload, cfg.tension, cfg.geometry).solve(pose).tensions_n
    params = PlantParams(cfg.anchors_m, float(cfg.sim.cable_ea_n), float(cfg.payload.mass_kg))
    return ReelPlant(params, [r.reel for r in cfg.reels], pose, turns, tensions)


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


def cmd_sim(args: argparse.Namespace) -> int:
    """Entry point of `cablebot sim`."""
    from controller.service.config import ConfigError, load_config
    from drivers import registry
    from drivers.bus import open_bus

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
    title = registry.family(cfg.drive.kind).title
    bus = open_bus(b.interface, b.channel, b.bitrate, **dict(b.options))
    try:
        try:
            bank = start_sim_bank(cfg, bus)
        except ValueError as exc:  # the physical plant cannot hold the power-up pose, ...
            log.error("simulated drives: %s", exc)
            return 2
        try:
            nodes = ",".join(str(n) for n in cfg.node_ids)
            log.info(
                "simulated %s nodes %s on %s %s (%s plant)",
                title,
                nodes,
                b.interface,
                b.channel,
                cfg.sim.plant,
            )
            print(f"READY {nodes}", flush=True)
            while not stop.wait(0.2):
                thread = bank.thread
                if thread is None or not thread.is_alive():
                    log.error("the simulated drives stopped serving")
                    return 1
        finally:
            bank.stop()
            stats = getattr(bank, "stats", None)
            if stats is not None:
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
    finally:
        bus.shutdown()
    return 0


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot sim`."""
    p = sub.add_parser(
        "sim",
        help="run the robot's simulated drives on its bus (own process)",
        description="Serve simulated drives ([drive] kind) for the config's reels until SIGTERM.",
    )
    p.add_argument("--config", type=Path, default=None, help="robot TOML (default: built-in)")
    p.set_defaults(func=cmd_sim)


if __name__ == "__main__":  # pragma: no cover
    from controller.cli import main

    sys.exit(main(["sim", *sys.argv[1:]]))
