"""`cablebot sim --config FILE`: the robot's simulated drives as their own process.

The drives are built by `controller.service.simulated` from the config (family, reels, bus,
power-up pose, `[sim]` section). Prints "READY <node ids>" on stdout once serving; runs until
SIGTERM/SIGINT (exit 0), then logs how fast it ran (ticks, late ticks, real-time factor) when the
bank counts them. The serving thread gets the daemon loop's scheduling (`loop.realtime`: SCHED_FIFO
one step below `loop.rt_priority`, a 1 us timer slack), as the in-process simulator does: a
starved simulator looks like a stale drive. With the physical plant it also publishes the
plant's ground truth on `<prefix>/sim/truth` (`controller.service.simulated.TRUTH_KEY`) through
a Zenoh peer session that connects to the daemon's listen endpoints.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

from controller.cli import exitcodes
from controller.service.simulated import start_sim_bank

log = logging.getLogger("cablebot.sim")


def cmd_sim(args: argparse.Namespace) -> int:
    """Entry point of `cablebot sim`."""
    from controller.service.config import ConfigError, load_config
    from controller.service.daemon import setup_logging
    from controller.service.runner import SWITCH_INTERVAL_S, TIMER_SLACK_NS, set_timer_slack
    from controller.service.simulated import schedule_sim_thread
    from drivers import registry
    from drivers.base import DriverError
    from drivers.bus import open_bus

    setup_logging(args.log_level, "%(levelname)s %(name)s: %(message)s")
    try:
        cfg = load_config(args.config)
    except (ConfigError, OSError) as exc:
        log.error("configuration: %s", exc)
        return 2
    b = cfg.bus
    title = registry.family(cfg.drive.kind).title
    try:
        bus = open_bus(b.interface, b.channel, b.bitrate, **dict(b.options))
    except (DriverError, OSError) as exc:  # as `cablebot run`: one line, could not start
        log.error("start-up failed: %s", exc)
        return exitcodes.REFUSED
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        # The scheduling of the daemon's loop (runner.start_loop): the serving thread
        # inherits the timer slack; a short GIL switch interval; SCHED_FIFO once started.
        slack = set_timer_slack(TIMER_SLACK_NS) if cfg.loop.realtime else "timer slack unchanged"
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
        try:
            bank = start_sim_bank(cfg, bus)
        except ValueError as exc:  # the physical plant cannot hold the power-up pose, ...
            log.error("simulated drives: %s", exc)
            return 2
        closers: list[Callable[[], object]] = []
        try:
            sched = schedule_sim_thread(cfg, bank.thread)
            nodes = ",".join(str(n) for n in cfg.node_ids)
            log.info(
                "simulated %s nodes %s on %s %s (%s plant; %s, %s)",
                title,
                nodes,
                b.interface,
                b.channel,
                cfg.sim.plant,
                sched,
                slack,
            )
            truth = _truth_feed(cfg, bank)
            if truth is not None:
                closers = [truth[0].stop, truth[1]]
            print(f"READY {nodes}", flush=True)
            while not stop.wait(0.2):
                thread = bank.thread
                if thread is None or not thread.is_alive():
                    log.error("the simulated drives stopped serving")
                    return 1
        finally:
            for close in closers:
                close()
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


def _truth_feed(cfg: Any, bank: Any) -> tuple[Any, Callable[[], object]] | None:
    """With the physical plant: publish its ground truth on `<prefix>/sim/truth` at the pose
    rate, through a Zenoh peer session that connects to the daemon's listen endpoints and
    listens nowhere; (the feed, the session's close), or None (no plant, or Zenoh failed: the
    drives are simulated all the same)."""
    plant = getattr(bank, "coupling", None)
    if plant is None:
        return None
    import zenoh

    from controller.service import zenoh_io
    from controller.service.simulated import TRUTH_KEY, TruthFeed

    zc = cfg.zenoh
    try:
        conf = zenoh_io.client_config(zc.listen, mode="peer", config_file=zc.config_file)
        session = zenoh.open(conf)
    except Exception as exc:
        log.warning("no ground truth on %s/%s: Zenoh: %s", zc.prefix, TRUTH_KEY, exc)
        return None
    pub = session.declare_publisher(f"{zc.prefix}/{TRUTH_KEY}", encoding=zenoh_io.JSON)
    period = max(1, int(cfg.loop.publish_every)) / float(cfg.loop.rate_hz)
    feed = TruthFeed(plant, pub.put, period).start()
    log.info("ground truth on %s/%s every %.4g s", zc.prefix, TRUTH_KEY, period)
    return feed, session.close


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot sim`."""
    p = sub.add_parser(
        "sim",
        help="run the robot's simulated drives on its bus (own process)",
        description="Serve simulated drives ([drive] kind) for the config's reels until SIGTERM.",
    )
    p.add_argument("--config", type=Path, default=None, help="robot TOML (default: built-in)")
    p.add_argument(
        "--log-level",
        default=os.environ.get("CABLEBOT_LOG_LEVEL", "INFO"),
        choices=["DEBUG", "INFO", "WARNING", "ERROR", "debug", "info", "warning", "error"],
        help="DEBUG also shows the libraries' own INFO lines (e.g. canopen's SDO traffic)",
    )
    p.set_defaults(func=cmd_sim)


if __name__ == "__main__":  # pragma: no cover
    from controller.cli import main

    sys.exit(main(["sim", *sys.argv[1:]]))
