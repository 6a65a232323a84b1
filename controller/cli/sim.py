"""`cablebot sim --config FILE`: the robot's simulated drives as their own process.

The drives are those of the config's reels, of the config's drive family (`[drive] kind`,
built through `drivers.registry`: simulated ODrive axes or simulated CiA 402 drives), on the
config's bus, initialised at the configured power-up pose (motor turns =
reel.position_rev(ipk(power-up pose)) with the config's reel offsets), with the `[sim]`
section's speed, acceleration and tick and, where the family uses them, its broadcast periods
and axis watchdog (ODrive: `watchdog_timeout_s`, on by default: a crashed daemon leaves the
axes IDLE, not running). The family's `[drive]` options apply too (CiA 402: counts per turn,
velocity units, EDS). Prints "READY <node ids>" on stdout once serving; runs until
SIGTERM/SIGINT (exit 0). `start_sim_bank` is the same thing as a thread, used by `cablebot run`
when `[sim] enabled`.
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


def sim_bank(cfg: Any, bus: Any) -> Any:
    """The config's simulated drives on `bus` (a `drivers.registry.SimBank`, not started).

    Raises ValueError / KinematicsError on an unusable power-up pose or settings.
    """
    from drivers import registry

    fam = registry.family(cfg.drive.kind)
    return fam.sim_bank(bus, cfg.node_ids, cfg.drive.options, sim_settings(cfg))


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
        bank = start_sim_bank(cfg, bus)
        try:
            nodes = ",".join(str(n) for n in cfg.node_ids)
            log.info("simulated %s nodes %s on %s %s", title, nodes, b.interface, b.channel)
            print(f"READY {nodes}", flush=True)
            while not stop.wait(0.2):
                thread = bank.thread
                if thread is None or not thread.is_alive():
                    log.error("the simulated drives stopped serving")
                    return 1
        finally:
            bank.stop()
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
