"""`cablebot run`: the controller daemon.

Loads the configuration, opens the bus, starts the simulated ODrive nodes in-process when
`[sim] enabled`, creates the reel driver, the `Controller` and the Zenoh interface, runs the
fixed-rate loop in its own thread and waits for SIGTERM/SIGINT. On a signal it stops any motion,
leaves the motors holding, stops the loop, closes Zenoh and the bus and exits 0 (well within
2 s). Logs go to stderr (no timestamps under journald). systemd `Type=notify`: READY=1 once the
robot holds (auto-arm) or every reel has answered, WATCHDOG=1 from the loop thread, STATUS=<state>.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import gc
import logging
import math
import os
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

from controller.commands import Arm, Stop
from controller.states import State

log = logging.getLogger("cablebot.daemon")

PR_SET_TIMERSLACK = 29
RT_PRIORITY = 50
"""Default SCHED_FIFO priority of the loop thread (`loop.rt_priority` overrides it)."""
TIMER_SLACK_NS = 1_000
SWITCH_INTERVAL_S = 0.0005
STOP_WAIT_S = 1.4
"""How long shutdown waits for a move to brake to a hold before stopping the loop."""


# -------------------------------------------------------------------------------- sd_notify


class Notifier:
    """systemd notification over $NOTIFY_SOCKET (a datagram socket); a no-op without it."""

    def __init__(self, env: dict[str, str] | None = None) -> None:
        env = dict(os.environ) if env is None else env
        self._addr: str | None = env.get("NOTIFY_SOCKET") or None
        self._sock: socket.socket | None = None
        if self._addr is not None:
            if self._addr.startswith("@"):
                self._addr = "\0" + self._addr[1:]
            try:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            except OSError as exc:
                log.warning("sd_notify unavailable: %s", exc)
        usec = env.get("WATCHDOG_USEC")
        pid = env.get("WATCHDOG_PID")
        self.watchdog_period_s = 0.0
        if usec and (pid is None or pid == str(os.getpid())):
            try:
                self.watchdog_period_s = int(usec) / 2e6
            except ValueError:
                log.warning("bad WATCHDOG_USEC %r ignored", usec)

    @property
    def enabled(self) -> bool:
        """True if a notification socket is configured."""
        return self._sock is not None

    def notify(self, message: str) -> None:
        """Send one notification (e.g. "READY=1"); errors are ignored (never blocks)."""
        if self._sock is None or self._addr is None:
            return
        with contextlib.suppress(OSError):
            self._sock.sendto(message.encode(), socket.MSG_DONTWAIT, self._addr)

    def close(self) -> None:
        """Close the socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None


# -------------------------------------------------------------------------------- real-time


def set_realtime(priority: int, tid: int = 0) -> str:
    """Try SCHED_FIFO at `priority` for thread `tid` (0: the calling thread); return what
    happened, for the log. Raises nothing."""
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as exc:
        return f"SCHED_FIFO {priority} not available ({exc}); running SCHED_OTHER"
    return f"SCHED_FIFO priority {priority}"


def set_timer_slack(slack_ns: int) -> str:
    """Try prctl(PR_SET_TIMERSLACK) for the calling thread; return what happened, for the log."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        rc = libc.prctl(PR_SET_TIMERSLACK, ctypes.c_ulong(slack_ns), 0, 0, 0)
    except (OSError, AttributeError) as exc:
        return f"timer slack unchanged ({exc})"
    if rc != 0:
        return f"timer slack unchanged (errno {ctypes.get_errno()})"
    return f"timer slack {slack_ns} ns"


# -------------------------------------------------------------------------------- logging


def setup_logging(level: str) -> None:
    """Log to stderr; no timestamps under journald (JOURNAL_STREAM set), which adds its own."""
    if os.environ.get("JOURNAL_STREAM"):
        fmt = "%(levelname)s %(name)s: %(message)s"
    else:
        fmt = "%(asctime)s %(levelname)s %(name)s: %(message)s"
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(fmt))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())


# -------------------------------------------------------------------------------- the daemon


def status_line(st: dict[str, Any]) -> str:
    """One human line from `Controller.status()`: state, pose, loop rate and jitter."""
    pose = st["pose"]
    if pose["valid"]:
        p = pose["position_m"]
        res_mm = pose["residual_m"] * 1e3
        pos = f"pose [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}] m residual {res_mm:.2f} mm"
    else:
        pos = "pose invalid"
    lp = st["loop"]
    j = lp["jitter_p99_s"]
    c = lp["compute_p99_s"]
    timing = (
        f"jitter p99 {j * 1e3:.3f} ms compute p99 {c * 1e3:.3f} ms"
        if j is not None and c is not None
        else "no ticks yet"
    )
    reason = f" ({st['reason']})" if st["reason"] else ""
    return (
        f"{st['state']}{reason} {pos}; loop {lp['rate_hz']:.0f} Hz ticks {lp['ticks']}"
        f" overruns {lp['overruns']} {timing}"
    )


@dataclass
class Stack:
    """A robot's running pieces, built by `build_stack` as `cablebot run` builds them."""

    cfg: Any
    bus: Any
    driver: Any
    controller: Any
    zenoh: Any | None
    closers: list[tuple[str, Callable[[], object]]] = field(default_factory=list)

    def close(self) -> None:
        """Close Zenoh, the simulated nodes and the buses (newest first); never raises."""
        _close_all(self.closers)
        self.closers = []


def build_stack(cfg: Any, *, zenoh: bool = True, sim_cfg: Any | None = None) -> Stack:
    """Open the bus, start in-process simulated nodes when `cfg.sim.enabled` (initialised from
    `sim_cfg`, default `cfg`), create the ODrive driver, the Controller and, with `zenoh`, the
    Zenoh interface as the controller's publisher.

    Raises whatever fails (bus, simulated nodes, Zenoh: e.g. its port is taken) after closing
    what was opened.
    """
    from controller.loop import Controller
    from controller.sim_cmd import start_sim_bank
    from drivers.bus import open_bus
    from drivers.odrive import ODriveReels

    closers: list[tuple[str, Callable[[], object]]] = []
    b = cfg.bus
    try:
        bus = open_bus(b.interface, b.channel, b.bitrate, **dict(b.options))
        closers.append(("bus", bus.shutdown))
        if cfg.sim.enabled:
            # python-can `virtual` buses only hear other bus objects: the sim gets its own.
            sim_bus = open_bus(b.interface, b.channel, b.bitrate, **dict(b.options))
            closers.append(("sim bus", sim_bus.shutdown))
            bank = start_sim_bank(sim_cfg if sim_cfg is not None else cfg, sim_bus)
            closers.append(("sim", bank.stop))
            sim_rt = "SCHED_OTHER"
            if cfg.loop.realtime:
                # The simulated nodes stand in for hardware: a starved sim thread on a busy
                # machine would look like a stale node. One step below the loop.
                for t in threading.enumerate():
                    if t.name == "sim-odrive" and t.native_id is not None:
                        sim_rt = set_realtime(max(1, _rt_priority(cfg) - 1), t.native_id)
            log.info(
                "simulated ODrive nodes %s started in-process (%s)",
                [r.node_id for r in cfg.reels],
                sim_rt,
            )
        driver = ODriveReels(
            bus, [r.node_id for r in cfg.reels], encoder_rtr=bool(cfg.loop.encoder_rtr)
        )
        controller = Controller(cfg, driver)
        iface = None
        if zenoh:
            from controller import zenoh_io

            iface = zenoh_io.ZenohInterface(cfg.zenoh, controller)
            try:
                iface.open()
            except Exception as exc:
                raise RuntimeError(
                    f"Zenoh interface failed to open on {list(cfg.zenoh.listen)}: {exc} "
                    "(is another cablebot daemon running? set [zenoh] listen)"
                ) from exc
            closers.append(("zenoh", iface.close))
            controller.publisher = iface
    except BaseException:
        _close_all(closers)
        raise
    return Stack(cfg, bus, driver, controller, iface, closers)


def start_loop(
    stack: Stack,
    stop: threading.Event,
    *,
    on_watchdog: Callable[[], None] | None = None,
    watchdog_period_s: float = 0.0,
    on_crash: Callable[[BaseException], None] | None = None,
) -> tuple[threading.Thread, list[str]]:
    """Run `stack.controller.run(stop)` in a loop thread, as the daemon does: SCHED_FIFO and a
    1 us timer slack for that thread (with `loop.realtime`), a short GIL switch interval, and
    the garbage collector frozen after start-up (`loop.gc_freeze`).

    Returns the thread and a list that the thread fills with the scheduling it obtained.
    If the loop raises, it is logged and `on_crash` is called from the loop thread; nothing
    is raised.
    """
    cfg = stack.cfg
    controller = stack.controller
    report: list[str] = []

    def loop_main() -> None:
        if cfg.loop.realtime:
            report.append(set_realtime(_rt_priority(cfg)))
        else:
            report.append("SCHED_OTHER (loop.realtime = false)")
        report.append(set_timer_slack(TIMER_SLACK_NS))
        try:
            controller.run(stop, on_watchdog=on_watchdog, watchdog_period_s=watchdog_period_s)
        except BaseException as exc:
            log.exception("control loop crashed")
            if on_crash is not None:
                on_crash(exc)

    # A woken loop thread waits for the GIL up to the switch interval (5 ms by default):
    # shorten it so other Python threads (Zenoh callbacks, an in-process sim) yield sooner.
    sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
    if cfg.loop.gc_freeze:
        gc.collect()
        gc.freeze()
    thread = threading.Thread(target=loop_main, name="cablebot-loop", daemon=True)
    thread.start()
    return thread, report


def run_daemon(
    config: Path | None,
    *,
    status_every_s: float = 5.0,
    auto_arm: bool | None = None,
    ready: Callable[[], None] | None = None,
) -> int:
    """Run the controller until SIGTERM/SIGINT; return the exit code (0 on a clean stop).

    Raises nothing for configuration or bus errors: they are logged and give exit code 2 / 1.
    """
    from controller.config import ConfigError, load_config

    try:
        cfg = load_config(config)
    except (ConfigError, OSError) as exc:
        log.error("configuration: %s", exc)
        return 2
    log.info("config: %s", _summary_text(cfg))
    log.debug("config details: %s", cfg.summary())

    shutdown = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        shutdown.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    notifier = Notifier()
    try:
        stack = build_stack(cfg)
    except Exception as exc:
        # A robot nobody can watch or stop over the network must not start: nothing is armed
        # yet, so failing here is safe (and systemd reports it).
        log.error("start-up failed: %s", exc)
        return 1
    controller = stack.controller
    driver = stack.driver

    stop_loop = threading.Event()
    crashed = threading.Event()

    def on_crash(exc: BaseException) -> None:
        crashed.set()
        shutdown.set()

    thread, rt_report = start_loop(
        stack,
        stop_loop,
        on_watchdog=lambda: notifier.notify("WATCHDOG=1"),
        watchdog_period_s=notifier.watchdog_period_s,
        on_crash=on_crash,
    )
    log.info(
        "control loop at %.0f Hz (%s)",
        cfg.loop.rate_hz,
        "gc frozen" if cfg.loop.gc_freeze else "gc normal",
    )

    want_arm = auto_arm if auto_arm is not None else _auto_arm(cfg)
    if want_arm:
        controller.submit(Arm())
        log.info("auto-arm requested")
    last_state: str | None = None
    announced_ready = False
    next_status = time.monotonic() + status_every_s
    arm_deadline = time.monotonic() + float(cfg.faults.arm_timeout_s) + 1.0
    while not shutdown.is_set():
        if rt_report:
            log.info("loop thread: %s", "; ".join(rt_report))
            rt_report.clear()
        state = controller.state.value
        if state != last_state:
            last_state = state
            notifier.notify(
                f"STATUS={state}" + (f" {controller.reason}" if controller.reason else "")
            )
        if not announced_ready and (
            (want_arm and state in (State.HOLDING.value, State.MOVING.value, State.FAULT.value))
            or (not want_arm and all(math.isfinite(r.stamp_s) for r in driver.read()))
            or time.monotonic() > arm_deadline
        ):
            announced_ready = True
            notifier.notify("READY=1")
            log.info("ready: %s", status_line(controller.status()))
            if ready is not None:
                ready()
        now = time.monotonic()
        if now >= next_status:
            next_status = now + (status_every_s if status_every_s > 0 else 5.0)
            line = status_line(controller.status())
            notifier.notify(f"STATUS={line}")
            if status_every_s > 0:
                log.info("%s", line)
        shutdown.wait(0.05)

    log.info("signal received: stopping motion and holding")
    notifier.notify("STOPPING=1")
    t0 = time.monotonic()
    if controller.state in (State.MOVING, State.HOLDING):
        controller.submit(Stop())
        while controller.state is State.MOVING and time.monotonic() - t0 < STOP_WAIT_S:
            time.sleep(0.01)
    controller.wait_for_saves(0.3)
    stop_loop.set()
    thread.join(0.5)
    final = controller.status()
    stack.close()
    notifier.close()
    log.info("stopped in %.3f s: %s", time.monotonic() - t0, status_line(final))
    return 1 if crashed.is_set() else 0


def _auto_arm(cfg: Any) -> bool:
    """`loop.auto_arm` if the config has it, else arm by itself only on the simulated robot."""
    value = cfg.loop.auto_arm
    if value is None:
        return bool(cfg.sim.enabled)
    return bool(value)


def _rt_priority(cfg: Any) -> int:
    return int(cfg.loop.rt_priority)


def _summary_text(cfg: Any) -> str:
    """One line: robot, source, bus, rate, homing, Zenoh, sim."""
    h = cfg.homing
    homing = (
        f"power-up pose {list(h.power_up_position_m)}"
        if h.power_up_position_m is not None
        else "no power-up pose"
    ) + (f", state file {h.state_file}" if h.state_file else ", no state file")
    return (
        f"robot {cfg.name!r} from {cfg.source}: {len(cfg.reels)} reels (nodes "
        f"{[r.node_id for r in cfg.reels]}) on {cfg.bus.interface} {cfg.bus.channel}; "
        f"{cfg.loop.rate_hz:g} Hz; {homing}; Zenoh prefix {cfg.zenoh.prefix}; "
        f"sim {'in-process' if cfg.sim.enabled else 'off'}"
    )


def _close_all(closers: list[tuple[str, Callable[[], object]]]) -> None:
    for name, close in reversed(closers):
        try:
            close()
        except Exception as exc:
            log.warning("closing %s: %s", name, exc)


def cmd_run(args: argparse.Namespace) -> int:
    """Entry point of `cablebot run`."""
    setup_logging(args.log_level)
    return run_daemon(args.config, status_every_s=args.status_every)


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot run`."""
    p = sub.add_parser(
        "run",
        help="run the controller daemon",
        description="Run the controller: fixed-rate loop, Zenoh interface, until SIGTERM.",
    )
    p.add_argument("--config", type=Path, default=None, help="robot TOML (default: built-in)")
    p.add_argument(
        "--log-level",
        default=os.environ.get("CABLEBOT_LOG_LEVEL", "INFO"),
        choices=["DEBUG", "INFO", "WARNING", "ERROR", "debug", "info", "warning", "error"],
    )
    p.add_argument(
        "--status-every",
        type=float,
        default=5.0,
        metavar="S",
        help="log a status line every S seconds (0: never)",
    )
    p.set_defaults(func=cmd_run)
