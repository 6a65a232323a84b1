"""`cablebot run`: the controller daemon.

Loads the configuration, opens the bus, starts the simulated drives in-process when
`[sim] enabled`, creates the reel driver of the configured drive family (`[drive] kind`, through
`drivers.registry`; a driver with a `configure()` step, CiA 402, is configured before the loop
runs), the `Controller` and the Zenoh interface, runs the fixed-rate loop in its own thread and
waits for SIGTERM/SIGINT.

Start-up: READY=1 (systemd `Type=notify`) only once every reel has answered (a heartbeat and
an encoder estimate from each node) and, with auto-arm, the arm has been tried (the robot
holds, or the arm was refused or faulted: the daemon is up and says why). A node that stays
silent gets a WARNING naming it, after `faults.arm_timeout_s` and then every status period
(`--status-every`, 1 s at least, 5 s when status lines are off) until it answers; auto-arm waits
for every reel too. WATCHDOG=1 comes from the loop thread, STATUS=<state> from here.

Shutdown: on a signal new motion is refused (`Controller.begin_shutdown`) and any motion brakes
to a hold at `limits.max_accel_mps2`; the daemon waits for it as long as the actual speed needs
(speed / acceleration, with a margin, at most `STOP_WAIT_MAX_S`), stops the loop, sends the
last set-point once more with zero velocity feed-forward (`Controller.send_final_hold`), closes
Zenoh and the bus and exits 0. Logs go to stderr (no timestamps under journald).
"""

from __future__ import annotations

import argparse
import contextlib
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
from types import FrameType, MappingProxyType
from typing import Any

from controller.core.commands import Arm
from controller.core.motion import BRAKE_ACCEL_SHARE
from controller.core.states import State
from controller.service.runner import start_loop
from controller.service.stream_log import StreamLog

log = logging.getLogger("cablebot.daemon")

RESTORED_POSE_WAIT_S = 1.0
"""How long after every reel answered a pose from the state file's offsets may take to appear
before the start-up warns that they give none."""
STOP_MARGIN_S = 0.5
STOP_MARGIN_FACTOR = 1.25
"""Shutdown waits for braking: the set-point's speed / max acceleration, times this factor (a
loaded loop runs the motion slower than the wall clock), plus `STOP_MARGIN_S`."""
STOP_WAIT_MAX_S = 10.0
"""The longest shutdown waits for a brake, whatever the speed and acceleration (systemd's
TimeoutStopSec in config/cablebot@.service is longer)."""
SILENT_WARN_EVERY_S = 5.0
"""Warning period for silent nodes when status lines are off (`--status-every 0`)."""


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
        """Seconds between WATCHDOG=1 pings: half the WATCHDOG_USEC systemd asked for (the
        sd_notify convention), when it is meant for this process; 0 = no watchdog, no pings."""
        if usec and (pid is None or pid == str(os.getpid())):
            try:
                self.watchdog_period_s = max(int(usec), 0) / 2e6
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


# -------------------------------------------------------------------------------- logging


_SYSLOG_PRIORITY = MappingProxyType(
    {"CRITICAL": 2, "ERROR": 3, "WARNING": 4, "INFO": 6, "DEBUG": 7}
)


class JournalFormatter(logging.Formatter):
    """Lines for journald: a `<N>` syslog priority prefix (so `journalctl -p err` filters) and
    no timestamp (journald adds its own)."""

    def __init__(self) -> None:
        super().__init__("%(levelname)s %(name)s: %(message)s")

    def format(self, record: logging.LogRecord) -> str:
        """Format `record`, each line of it prefixed with its priority."""
        prefix = f"<{_SYSLOG_PRIORITY.get(record.levelname, 6)}>"
        return "\n".join(prefix + line for line in super().format(record).splitlines())


OWN_LOGGERS = ("cablebot", "controller", "drivers")
"""Top-level names of cablebot's own loggers; every other logger is a third party's."""


class ThirdPartyFilter(logging.Filter):
    """Passes cablebot's own records, and a third-party library's (e.g. canopen, which logs
    every SDO at INFO) only from WARNING up, so they do not bury cablebot's lines."""

    def filter(self, record: logging.LogRecord) -> bool:
        """True if `record` is to be logged. Raises nothing."""
        if record.levelno >= logging.WARNING:
            return True
        return record.name.partition(".")[0] in OWN_LOGGERS


def setup_logging(level: str, fmt: str | None = None) -> None:
    """Log to stderr at `level`; under journald (JOURNAL_STREAM set) with priority prefixes and
    no time, else with `fmt` (default: with the time). Third-party libraries log from WARNING
    up unless `level` is DEBUG. Raises ValueError on an unknown level name."""
    handler = logging.StreamHandler(sys.stderr)
    if os.environ.get("JOURNAL_STREAM"):
        handler.setFormatter(JournalFormatter())
    else:
        handler.setFormatter(
            logging.Formatter(fmt or "%(asctime)s %(levelname)s %(name)s: %(message)s")
        )
    root = logging.getLogger()
    root.setLevel(level.upper())
    if root.level > logging.DEBUG:
        handler.addFilter(ThirdPartyFilter())
    root.handlers[:] = [handler]


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
    sim_bank: Any | None = None
    """The simulated drives (`[sim] enabled`), else None."""

    def close(self) -> None:
        """Close Zenoh, the simulated nodes and the buses (newest first); never raises."""
        _close_all(self.closers)
        self.closers = []


def build_stack(cfg: Any, *, zenoh: bool = True, sim_cfg: Any | None = None) -> Stack:
    """Open the bus, start in-process simulated drives when `cfg.sim.enabled` (initialised from
    `sim_cfg`, default `cfg`), create the driver of the configured drive family (and configure
    its drives when it has a `configure()` step), the Controller and, with `zenoh`, the Zenoh
    interface as the controller's publisher.

    Raises whatever fails (bus, simulated drives, Zenoh: e.g. its port is taken) after closing
    what was opened; drives that cannot be configured raise RuntimeError naming the node and
    the step.
    """
    from controller.service.loop import Controller
    from controller.service.simulated import schedule_sim_thread, start_sim_bank
    from drivers import registry
    from drivers.base import ConfigurableDriver, DriverError
    from drivers.bus import open_bus

    closers: list[tuple[str, Callable[[], object]]] = []
    b = cfg.bus
    fam = registry.family(cfg.drive.kind)
    bank: Any = None
    try:
        bus = open_bus(b.interface, b.channel, b.bitrate, **dict(b.options))
        closers.append(("bus", bus.shutdown))
        if cfg.sim.enabled:
            # python-can `virtual` buses only hear other bus objects: the sim gets its own.
            sim_bus = open_bus(b.interface, b.channel, b.bitrate, **dict(b.options))
            closers.append(("sim bus", sim_bus.shutdown))
            bank = start_sim_bank(sim_cfg if sim_cfg is not None else cfg, sim_bus)
            closers.append(("sim", bank.stop))
            sim_rt = schedule_sim_thread(cfg, bank.thread)
            log.info(
                "simulated %s nodes %s started in-process (%s)",
                fam.title,
                list(cfg.node_ids),
                sim_rt,
            )
        loop_settings = registry.LoopSettings(
            period_s=1.0 / float(cfg.loop.rate_hz),
            stale_timeout_s=float(cfg.faults.stale_timeout_s),
            encoder_rtr=bool(cfg.loop.encoder_rtr),
            torque_rtr=cfg.loop.torque_telemetry == "rtr",
            torque_rtr_period_s=float(cfg.loop.torque_rtr_period_s),
        )
        driver = fam.open_driver(bus, cfg.node_ids, cfg.drive.options, loop_settings)
        if getattr(driver, "fast_path", False):
            log.info(
                "SocketCAN fast path on %s: batched kernel I/O, kernel filters for nodes %s",
                b.channel,
                list(cfg.node_ids),
            )
        if isinstance(driver, ConfigurableDriver):
            t0 = time.monotonic()
            try:
                driver.configure()
            except DriverError as exc:
                raise RuntimeError(f"configuring the {fam.title}s failed: {exc}") from exc
            log.info(
                "%s nodes %s configured in %.2f s",
                fam.title,
                list(cfg.node_ids),
                time.monotonic() - t0,
            )
        controller = Controller(cfg, driver)
        iface = None
        if zenoh:
            from controller.service import zenoh_io
            from controller.service.config import robot_description

            iface = zenoh_io.ZenohInterface(
                cfg.zenoh, controller, robot=robot_description(cfg) if cfg.text else None
            )
            try:
                iface.open()
            except Exception as exc:
                raise RuntimeError(zenoh_open_problem(cfg.zenoh, exc)) from exc
            closers.append(("zenoh", iface.close))
            controller.publisher = iface
            rcfg = getattr(cfg, "ros2", None)
            if rcfg is not None and rcfg.enabled:
                from controller.service.pose import FanOutPublisher
                from controller.service.ros2.node import Ros2Node

                ros2 = Ros2Node(rcfg, iface)
                ros2.open()
                closers.append(("ros2", ros2.close))
                iface.status_extras["ros2"] = ros2.stats
                controller.publisher = FanOutPublisher(iface, ros2)
            if cfg.sim.enabled:
                start_truth_feed(cfg, bank, iface, closers)
    except BaseException:
        _close_all(closers)
        raise
    return Stack(cfg, bus, driver, controller, iface, closers, bank)


def start_truth_feed(
    cfg: Any, bank: Any, iface: Any, closers: list[tuple[str, Callable[[], object]]]
) -> bool:
    """With the physical plant (`bank.coupling`): publish its ground truth on
    `<prefix>/sim/truth` through the open Zenoh interface `iface` at the pose rate, its stop
    added to `closers`; True if started, False without a plant.  Raises what
    `ZenohInterface.json_publisher` raises."""
    if getattr(bank, "coupling", None) is None:
        return False
    from controller.service.simulated import TRUTH_KEY, TruthFeed

    period = max(1, int(cfg.loop.publish_every)) / float(cfg.loop.rate_hz)
    feed = TruthFeed(bank.coupling, iface.json_publisher(TRUTH_KEY), period).start()
    closers.append(("sim truth", feed.stop))
    return True


def zenoh_open_problem(zcfg: Any, exc: BaseException) -> str:
    """The start-up error for a Zenoh session that failed to open: what failed, the `[zenoh]`
    keys that decide it, and, only when the address is taken, the hint that another daemon
    may be running."""
    keys = [f"listen = {list(zcfg.listen)}"]
    if zcfg.connect:
        keys.append(f"connect = {list(zcfg.connect)}")
    if zcfg.config_file:
        keys.append(f"config_file = {zcfg.config_file!r}")
    text = str(exc)
    msg = f"Zenoh interface failed to open ([zenoh] {', '.join(keys)}): {text}"
    if "in use" in text.lower() or "os error 98" in text.lower():
        return (
            msg + " (the address is taken: is another cablebot daemon running? set [zenoh] listen)"
        )
    return msg + " (check [zenoh] listen, connect and config_file)"


def silent_nodes(readings: Any) -> list[tuple[int, int, str]]:
    """(node id, cable number from 1, what is missing) for every axis that has not sent both a
    heartbeat and an encoder estimate yet."""
    out = []
    for i, r in enumerate(readings):
        missing = []
        if not math.isfinite(r.heartbeat_stamp_s):
            missing.append("no heartbeat")
        if not math.isfinite(r.stamp_s):
            missing.append("no encoder estimate")
        if missing:
            out.append((int(r.node_id), i + 1, " and ".join(missing)))
    return out


def brake_wait_s(brake_time_s: float, max_speed_mps: float, max_accel_mps2: float) -> float:
    """How long shutdown waits for a brake that needs `brake_time_s` at the set-point's speed:
    times `STOP_MARGIN_FACTOR` plus `STOP_MARGIN_S`, at most what the slowest stop from the
    fastest allowed motion needs (along corner arcs, `BRAKE_ACCEL_SHARE`), and never more than
    `STOP_WAIT_MAX_S`. Raises nothing (a non-finite input gives the cap)."""
    # the slowest stop: from max speed along corner arcs, at their share of the acceleration
    longest = max_speed_mps / (max_accel_mps2 * BRAKE_ACCEL_SHARE) * STOP_MARGIN_FACTOR
    longest += STOP_MARGIN_S
    wait = brake_time_s * STOP_MARGIN_FACTOR + STOP_MARGIN_S
    if not math.isfinite(wait) or not math.isfinite(longest):
        return STOP_WAIT_MAX_S
    return min(wait, longest, STOP_WAIT_MAX_S)


class StartupWatch:
    """The daemon's start-up duties, stepped from its main thread (every 50 ms).

    * Names every node that has not answered yet (no heartbeat or no encoder estimate) in a
      WARNING, first after `faults.arm_timeout_s`, then every `status_every_s` (1 s at least;
      `SILENT_WARN_EVERY_S` when status lines are off) until it answers, then logs that it did.
    * Looks at each node's first heartbeat and logs what the drive family notes about it
      (`drivers.registry`; ODrive: an axis already in closed loop before cablebot armed it is
      driven by someone else, or its watchdog is off and a previous controller left it running
      (WARNING); WATCHDOG_TIMER_EXPIRED shows that its watchdog works (INFO)).
    * With `want_arm`, submits Arm once every reel has answered.
    * Sends READY=1 once every reel has answered and, with `want_arm`, the arm has been tried
      (holding, faulted or refused: the daemon is up and its status says how it is).
    * Once every reel has answered, looks at the pose the state file's homing offsets give and
      warns (`offsets.restored_pose_problem`) when it lies outside the workspace or more than
      `faults.tracking_max_m` from the power-up pose, or is no pose at all after
      `RESTORED_POSE_WAIT_S`: the offsets are stale when a drive restarted since.

    STATUS= follows the controller's state (or names the nodes waited for). Raises nothing.
    """

    def __init__(
        self,
        cfg: Any,
        controller: Any,
        driver: Any,
        notifier: Notifier,
        *,
        want_arm: bool,
        status_every_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cfg = cfg
        self.controller = controller
        self.driver = driver
        self.notifier = notifier
        self.want_arm = want_arm
        self.ready = False
        self.arm_future: Any = None
        self._clock = clock
        self._started = clock()
        self._warn_every_s = max(1.0, status_every_s if status_every_s > 0 else SILENT_WARN_EVERY_S)
        self._next_warn = self._started + float(cfg.faults.arm_timeout_s)
        self._warned: set[int] = set()
        self._seen: set[int] = set()
        self._last_status: str | None = None
        self._restored_from: float | None = None
        """When every reel first answered, until the restored pose has been looked at."""
        self._restored_done = getattr(controller, "home_source", None) != "state_file"
        self._bus_name = f"{cfg.bus.interface} {cfg.bus.channel}"
        from drivers import registry

        self._family = registry.family(cfg.drive.kind)
        self._title = self._family.title

    def step(self) -> bool:
        """Do what is due now; True exactly once, when the daemon has become ready."""
        now = self._clock()
        readings = self.driver.read()
        self._first_heartbeats(readings)
        silent = silent_nodes(readings)
        if silent and now >= self._next_warn:
            self._next_warn = now + self._warn_every_s
            log.warning(
                "no answer from %s %s on %s after %.1f s: check power, wiring, CAN node ids "
                "and bit rate; READY withheld until every reel answers",
                self._title,
                ", ".join(f"node {n} (cable {c}: {what})" for n, c, what in silent),
                self._bus_name,
                now - self._started,
            )
            self._warned.update(n for n, _, _ in silent)
            self._status(f"waiting for {self._title} node(s) {[n for n, _, _ in silent]}")
        if self._warned:
            answered = self._warned - {n for n, _, _ in silent}
            for n in sorted(answered):
                log.info("%s node %d answered after %.1f s", self._title, n, now - self._started)
            self._warned -= answered
        if not silent and not self._restored_done:
            self._look_at_restored_pose(now)
        if self.want_arm and self.arm_future is None and not silent:
            self.arm_future = self.controller.submit(Arm())
            log.info("auto-arm requested (every reel answered)")
        state = self.controller.state.value
        if not self._warned:
            reason = self.controller.reason
            self._status(state + (f" {reason}" if reason else ""))
        if self.ready or silent:
            return False
        fut = self.arm_future
        if self.want_arm and not (fut is not None and fut.done() and state != State.ARMING.value):
            return False
        self.ready = True
        if fut is not None and fut.exception() is not None:
            log.warning("auto-arm refused: %s", fut.exception())
        self.notifier.notify("READY=1")
        log.info("ready: %s", status_line(self.controller.status()))
        return True

    def _look_at_restored_pose(self, now: float) -> None:
        """Warn once about a pose from stale state-file offsets (class docstring)."""
        from controller.service.offsets import restored_pose_problem

        ctl = self.controller
        if self._restored_from is None:
            self._restored_from = now
        if ctl.home_source != "state_file":  # homed again meanwhile
            self._restored_done = True
            return
        pose = ctl.pose_m if ctl.pose_valid else None
        if pose is None and now - self._restored_from < RESTORED_POSE_WAIT_S:
            return  # the loop solves it within a tick or two of the readings
        self._restored_done = True
        homing = self.cfg.homing
        problem = restored_pose_problem(
            pose,
            ctl.workspace.check_point,
            homing.power_up_position_m,
            float(self.cfg.faults.tracking_max_m),
            str(homing.state_file),
        )
        if problem is not None:
            log.warning("%s", problem)

    def _status(self, text: str) -> None:
        if text != self._last_status:
            self._last_status = text
            self.notifier.notify(f"STATUS={text}")

    def _first_heartbeats(self, readings: Any) -> None:
        """What the drive family notes about each node's first heartbeat (`drivers.registry`:
        ODrive: an axis in closed loop before cablebot armed it, a watchdog that stopped it)."""
        for r in readings:
            if r.node_id in self._seen or not math.isfinite(r.heartbeat_stamp_s):
                continue
            self._seen.add(r.node_id)
            note = self._family.note_first_heartbeat(r, self.arm_future is not None)
            if note is not None:
                log.log(note[0], "%s", note[1])


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
    from controller.service.config import ConfigError, load_config

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
        controller.runner(),
        cfg.loop,
        stop_loop,
        on_watchdog=(lambda: notifier.notify("WATCHDOG=1"))
        if notifier.watchdog_period_s > 0.0
        else None,
        watchdog_period_s=notifier.watchdog_period_s,
        on_crash=on_crash,
    )
    log.info(
        "control loop at %.0f Hz (%s)",
        cfg.loop.rate_hz,
        "gc frozen" if cfg.loop.gc_freeze else "gc normal",
    )

    watch = StartupWatch(
        cfg,
        controller,
        driver,
        notifier,
        want_arm=auto_arm if auto_arm is not None else _auto_arm(cfg),
        status_every_s=status_every_s,
    )
    stream_log = StreamLog(controller)
    next_status = time.monotonic() + status_every_s
    while not shutdown.is_set():
        stream_log.step()
        if rt_report:
            log.info("loop thread: %s", "; ".join(rt_report))
            rt_report.clear()
        if watch.step() and ready is not None:
            ready()
        now = time.monotonic()
        if now >= next_status:
            next_status = now + (status_every_s if status_every_s > 0 else 5.0)
            line = status_line(controller.status())
            notifier.notify(f"STATUS={line}")
            if status_every_s > 0:
                log.info("%s", line)
        shutdown.wait(0.05)

    log.info("signal received: refusing new motion, braking to a hold")
    notifier.notify("STOPPING=1")
    t0 = time.monotonic()
    lim = cfg.limits
    brake_s = controller.brake_time_s()
    vx, vy, vz = controller.planner.velocity_mps
    start_speed_mps = math.sqrt(vx * vx + vy * vy + vz * vz)
    start_sp = controller.setpoint_m
    controller.begin_shutdown()
    wait_s = brake_wait_s(brake_s, float(lim.max_speed_mps), float(lim.max_accel_mps2))
    deadline = t0 + wait_s
    # A pre-tension ends at the queued stop (the drives hold where the reels are).
    while (
        controller.state is State.MOVING or controller.state is State.PRETENSIONING
    ) and time.monotonic() < deadline:
        time.sleep(0.01)
    if controller.state is State.MOVING:
        log.warning("motion not at rest after %.2f s; holding the last set-point", wait_s)
    elif brake_s > 0.0:
        end_sp = controller.setpoint_m
        travel = (
            math.dist(start_sp, end_sp) if start_sp is not None and end_sp is not None else math.nan
        )
        log.info(
            "braked from %.3f m/s to rest in %.3f s over %.3f m",
            start_speed_mps,
            time.monotonic() - t0,
            travel,
        )
    controller.wait_for_saves(0.3)
    stop_loop.set()
    thread.join(1.0)
    if thread.is_alive():
        log.error("control loop thread did not stop: final hold not sent")
    elif controller.send_final_hold():
        log.info("final hold sent: last set-point, zero velocity feed-forward")
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


def _summary_text(cfg: Any) -> str:
    """One line: robot, source, bus, rate, homing, Zenoh, sim."""
    h = cfg.homing
    homing = (
        f"power-up pose {list(h.power_up_position_m)}"
        if h.power_up_position_m is not None
        else "no power-up pose"
    ) + (f", state file {h.state_file}" if h.state_file else ", no state file")
    from drivers import registry

    title = registry.family(cfg.drive.kind).title
    return (
        f"robot {cfg.name!r} from {cfg.source}: {len(cfg.reels)} reels ({title} nodes "
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
        help="DEBUG also shows the libraries' own INFO lines (e.g. canopen's SDO traffic)",
    )
    p.add_argument(
        "--status-every",
        type=float,
        default=5.0,
        metavar="S",
        help="log a status line every S seconds (0: never)",
    )
    p.set_defaults(func=cmd_run)
