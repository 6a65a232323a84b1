"""`cablebot monitor`: a terminal dashboard of a running daemon, with stop and e-stop keys.

Shows the state and its reason (a fault in red, across the screen), the pose and the
set-point (both from one status sample), every axis (its state and fault as the drive names
them, in green when it is ready, age of the last reading, cable tension when the status
carries `tensions_n`), loop and bus figures, samples missed from the pose stream, and the
recent state changes (`<prefix>/state`). Keys: `s` stop (brake to a hold), `e` or space
e-stop, `q` quit. Needs the `rich` library (`pip install 'cablebot[monitor]'`).

Built on the client library (`controller.client.Robot`). Threads: Zenoh's callbacks store the
latest pose and state changes; a poller queries `<prefix>/status` four times a second (the
pose and the set-point shown come from it, one instant); keys send commands from short-lived
threads so the screen never waits on a reply. The main thread reads keys and redraws.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from controller.cli import exitcodes
from controller.cli.zenoh_threads import start_zenoh_thread
from controller.client.model import Pose, StateChange

if TYPE_CHECKING:
    from controller.client.robot import Robot

STATUS_PERIOD_S = 0.25
POSE_STALE_S = 1.0
RECENT_STATES = 8
STATE_STYLES = {
    "HOLDING": "bold green",
    "MOVING": "bold cyan",
    "ARMING": "bold yellow",
    "PRETENSIONING": "bold yellow",
    "DISARMED": "bold",
    "FAULT": "bold white on red",
    "ESTOPPED": "bold white on red",
}


@dataclass
class Snapshot:
    """What the screen shows, copied under the lock for one redraw."""

    pose: dict[str, Any] | None = None
    pose_rx_s: float | None = None
    received: int = 0
    missed: int = 0
    status: dict[str, Any] | None = None
    status_rx_s: float | None = None
    status_error: str | None = None
    states: list[tuple[int, str, str | None]] = field(default_factory=list)
    message: tuple[str, str] | None = None  # (text, style)


class MonitorData:
    """The latest pose, status and state changes, written by Zenoh's threads (thread-safe)."""

    def __init__(self) -> None:
        from controller.cli.formats import SeqGaps

        self._lock = threading.Lock()
        self._pose: Pose | None = None
        self._pose_rx_s: float | None = None
        self._gaps = SeqGaps()
        self._status: dict[str, Any] | None = None
        self._status_rx_s: float | None = None
        self._status_error: str | None = None
        self._states: deque[tuple[int, str, str | None]] = deque(maxlen=RECENT_STATES)
        self._message: tuple[str, str] | None = None

    def on_pose(self, pose: Pose) -> None:
        """A pose sample arrived (Zenoh's thread: kept as it is, decoded for a redraw)."""
        with self._lock:
            self._gaps.update(pose.seq)
            self._pose = pose
            self._pose_rx_s = pose.received_s

    def on_state(self, change: StateChange) -> None:
        """A state change arrived."""
        entry = (change.stamp_ns or time.time_ns(), change.state, change.reason)
        with self._lock:
            self._states.append(entry)

    def on_status(self, status: dict[str, Any] | None, error: str | None) -> None:
        """A status reply (or why there is none)."""
        with self._lock:
            if status is not None:
                self._status = status
                self._status_rx_s = time.monotonic()
                if not self._states and status.get("state"):
                    stamp = int(status.get("state_stamp_ns") or time.time_ns())
                    self._states.append((stamp, str(status["state"]), status.get("reason")))
            self._status_error = error

    def set_message(self, text: str, style: str) -> None:
        """The outcome of the last key (shown under the state)."""
        with self._lock:
            self._message = (text, style)

    def snapshot(self) -> Snapshot:
        """A consistent copy for one redraw."""
        with self._lock:
            return Snapshot(
                pose=None if self._pose is None else self._pose.as_dict(),
                pose_rx_s=self._pose_rx_s,
                received=self._gaps.received,
                missed=self._gaps.missed,
                status=self._status,
                status_rx_s=self._status_rx_s,
                status_error=self._status_error,
                states=list(self._states),
                message=self._message,
            )


# --------------------------------------------------------------------------------------------
# Drawing


def _num(v: Any, fmt: str, scale: float = 1.0, none: str = "-") -> str:
    if isinstance(v, int | float) and not isinstance(v, bool):
        return format(float(v) * scale, fmt)
    return none


def _xyz(p: Any) -> str:
    if isinstance(p, list) and len(p) == 3:
        return f"x {p[0]:+9.4f}  y {p[1]:+9.4f}  z {p[2]:+8.4f} m"
    return "not valid"


def render(
    snap: Snapshot, now_s: float, pose_rate_hz: float | None, title: str, *, keys: bool = True
) -> Any:
    """The dashboard for `snap` as a rich renderable (`keys`: whether key presses are read)."""
    from rich import box
    from rich.console import Group
    from rich.panel import Panel
    from rich.table import Table
    from rich.text import Text

    from controller.cli.formats import axis_fault_text, axis_state_text, status_tensions_n

    st = snap.status or {}
    pose = snap.pose or {}
    state = str(pose.get("state") or st.get("state") or "?")
    reason = st.get("reason") if st.get("state") == state else None
    if reason is None and snap.states and snap.states[-1][1] == state:
        reason = snap.states[-1][2]
    parts: list[Any] = []

    head = Text()
    head.append("cablebot monitor  ", style="bold")
    head.append(title, style="dim")
    if keys:
        head.append("    keys: ", style="dim")
        head.append("s", style="bold")
        head.append(" stop  ", style="dim")
        head.append("e/space", style="bold red")
        head.append(" E-STOP  ", style="dim")
        head.append("q", style="bold")
        head.append(" quit", style="dim")
    else:
        head.append("    no keys (input is not a terminal): Ctrl-C quits", style="bold yellow")
    parts.append(head)

    line = Text("state  ")
    line.append(f" {state} ", style=STATE_STYLES.get(state, "bold"))
    if reason and state not in ("FAULT", "ESTOPPED"):
        line.append(f"  ({reason})", style="dim")
    parts.append(line)
    if state == "FAULT":
        parts.append(
            Panel(
                Text(f"FAULT: {reason or 'no reason given'}", style="bold red"),
                subtitle="`cablebot reset` clears it and idles the motors: support the load first",
                border_style="red",
            )
        )
    elif state == "ESTOPPED":
        parts.append(
            Panel(
                Text(f"ESTOPPED: {reason or 'estop'}", style="bold red"),
                subtitle="`cablebot reset` then `arm` to continue",
                border_style="red",
            )
        )
    if snap.message is not None:
        parts.append(Text(snap.message[0], style=snap.message[1]))

    age = None if snap.pose_rx_s is None else now_s - snap.pose_rx_s
    t = Table(box=None, show_header=False, padding=(0, 1))
    t.add_column(style="bold")
    t.add_column()
    if age is None or age > POSE_STALE_S:
        since = "yet" if age is None else f"for {age:.1f} s"
        t.add_row("pose", Text(f"no pose sample {since}", style="bold red"))
    else:
        # The pose beside the set-point must be from the same instant: the status carries both
        # (one snapshot of the controller); the pose stream runs ahead of a status polled at
        # STATUS_PERIOD_S (0.5 m at 1 m/s). The stream's sample is shown only without a status.
        status_pose = st.get("pose")
        shown: dict[str, Any] = status_pose if isinstance(status_pose, dict) else pose
        res = shown.get("residual_m")
        t.add_row(
            "pose",
            f"{_xyz(shown.get('position_m'))}   residual {_num(res, '.2f', 1e3)} mm",
        )
    sp = st.get("setpoint_m")
    t.add_row("set-point", _xyz(sp) if sp is not None else "none")
    pt = st.get("pretension") or {}
    if pt.get("active"):
        t.add_row(
            "pretension",
            Text(
                f"{_num(pt.get('elapsed_s'), '.1f')} s, fastest cable "
                f"{_num(pt.get('fastest_cable_mps'), '.2f', 1e3)} mm/s; home at "
                f"{_xyz(pt.get('position_m'))}",
                style="yellow",
            ),
        )
    rate = "-" if pose_rate_hz is None else f"{pose_rate_hz:.0f}/s"
    missed = Text(f"{snap.missed} missed", style="bold yellow" if snap.missed else "")
    stream = Text(f"seq {pose.get('seq', '-')}  {rate}  {snap.received} received, ")
    stream.append_text(missed)
    t.add_row("stream", stream)
    lp = st.get("loop") or {}
    t.add_row(
        "loop",
        f"{_num(lp.get('rate_hz'), '.0f')} Hz  ticks {lp.get('ticks', '-')}  overruns"
        f" {lp.get('overruns', '-')}  jitter p99 {_num(lp.get('jitter_p99_s'), '.3f', 1e3)} ms"
        f"  compute p99 {_num(lp.get('compute_p99_s'), '.3f', 1e3)} ms",
    )
    bus = st.get("bus") or {}
    bus_text = Text(
        f"rx {bus.get('frames_rx', '-')}  tx {bus.get('frames_tx', '-')}  errors"
        f" {bus.get('bus_errors', '-')}  decode errors {bus.get('decode_errors', '-')}"
        f"  dropped {bus.get('dropped', '-')}"
    )
    if bus.get("last_error"):
        bus_text.append(f"  last: {bus['last_error']}", style="yellow")
    t.add_row("bus", bus_text)
    if snap.status_error:
        t.add_row("status", Text(snap.status_error, style="bold red"))
    parts.append(t)

    axes = st.get("axes") or []
    tensions = status_tensions_n(st) if st else None
    at = Table(box=box.SIMPLE_HEAD, padding=(0, 1), show_edge=False)
    for name in ("node", "axis state", "fault", "reading", "heartbeat"):
        at.add_column(name, no_wrap=name != "errors")
    if tensions is not None:
        at.add_column("tension", justify="right")
    for i, ax in enumerate(axes):
        fault = axis_fault_text(ax)
        row: list[Any] = [
            str(ax.get("node_id")),
            Text(axis_state_text(ax), style="green" if ax.get("ready") else "yellow"),
            Text(fault, style="dim" if fault == "none" else "bold red"),
            f"{_num(ax.get('age_s'), '.1f', 1e3, 'never')} ms",
            f"{_num(ax.get('heartbeat_age_s'), '.0f', 1e3, 'never')} ms",
        ]
        if tensions is not None:
            v = tensions[i] if i < len(tensions) else None
            row.append("-" if v is None else f"{v:.1f} N")
        at.add_row(*row)
    if axes:
        parts.append(at)

    recent = Table(box=None, show_header=False, padding=(0, 1), title_justify="left")
    recent.add_column(style="dim")
    recent.add_column()
    recent.add_column(style="dim")
    for stamp_ns, s, why in reversed(snap.states):
        clock = time.strftime("%H:%M:%S", time.localtime(stamp_ns / 1e9))
        recent.add_row(clock, Text(s, style=STATE_STYLES.get(s, "")), why or "")
    parts.append(Text("recent state changes", style="bold"))
    parts.append(recent)
    return Group(*parts)


# --------------------------------------------------------------------------------------------
# Keys and commands


@contextlib.contextmanager
def _keys(fd: int | None) -> Iterator[None]:
    """Single key presses on `fd` (a terminal) while inside; restores the terminal after."""
    if fd is None:
        yield
        return
    import termios
    import tty

    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def _send(robot: Robot, verb: str, data: MonitorData) -> None:
    """Send `verb` and show the outcome (runs in its own thread)."""
    from controller.cli.formats import format_reply
    from controller.cli.session import DaemonAbsent, Refused

    try:
        reply = robot.command(verb)
    except Refused as exc:
        data.set_message(f"{verb}: refused: {exc}", "bold red")
    except DaemonAbsent as exc:
        data.set_message(f"{verb}: no answer ({exc})", "bold red")
    except Exception as exc:  # a closed session at exit, Zenoh errors: show, never crash
        data.set_message(f"{verb}: failed: {exc}", "bold red")
    else:
        style = "bold red" if verb == "estop" else "bold yellow"
        data.set_message(format_reply(verb, dict(reply.raw)), style)


def _poll_status(robot: Robot, data: MonitorData, stop: threading.Event) -> None:
    from controller.cli.session import DaemonAbsent, Refused

    while not stop.is_set():
        try:
            data.on_status(dict(robot.status().raw), None)
        except (DaemonAbsent, Refused) as exc:
            data.on_status(None, f"no status: {exc}")
        except Exception as exc:  # the session closing at exit
            if stop.is_set():
                return
            data.on_status(None, f"no status: {exc}")
        stop.wait(STATUS_PERIOD_S)


def cmd_monitor(args: argparse.Namespace) -> int:
    """`cablebot monitor`: the dashboard until `q` or Ctrl-C."""
    try:
        from rich.console import Console
        from rich.live import Live
    except ImportError:
        print(
            "cablebot: monitor needs the rich library: pip install 'cablebot[monitor]'",
            file=sys.stderr,
        )
        return exitcodes.REFUSED
    from controller.cli.session import run_with_session

    if not args.refresh > 0.0:
        print(f"cablebot: --refresh must be > 0, got {args.refresh}", file=sys.stderr)
        return exitcodes.USAGE
    prefix = args.prefix.rstrip("/")

    def body(session: Any) -> int:
        from controller.cli.client import robot_of

        data = MonitorData()
        robot = robot_of(args, session)
        subs: list[Any] = [robot.on_pose(data.on_pose), robot.on_state(data.on_state)]
        stop = threading.Event()
        poller = start_zenoh_thread(_poll_status, robot, data, stop, name="cablebot-monitor-status")
        fd: int | None = None
        with contextlib.suppress(AttributeError, ValueError, OSError):
            if sys.stdin.isatty():
                fd = sys.stdin.fileno()
        title = f"{prefix} via {args.connect}"
        console = Console()
        period_s = 1.0 / args.refresh
        last_count, last_s, rate = 0, time.monotonic(), None
        try:
            with _keys(fd), Live(console=console, screen=True, auto_refresh=False) as live:
                while True:
                    now = time.monotonic()
                    snap = data.snapshot()
                    if now - last_s >= 1.0:
                        rate = (snap.received - last_count) / (now - last_s)
                        last_count, last_s = snap.received, now
                    live.update(render(snap, now, rate, title, keys=fd is not None), refresh=True)
                    key = _read_key(fd, period_s)
                    if key in ("q", "Q"):
                        return exitcodes.OK
                    verb = {"s": "stop", "S": "stop", "e": "estop", "E": "estop", " ": "estop"}.get(
                        key or ""
                    )
                    if verb is not None:
                        data.set_message(f"{verb}: sent …", "bold yellow")
                        start_zenoh_thread(
                            _send, robot, verb, data, name=f"cablebot-monitor-{verb}"
                        )
        finally:
            stop.set()
            for sub in subs:
                sub.close()
            poller.join(args.timeout + 1.0)

    return run_with_session(args, body)


def _read_key(fd: int | None, timeout_s: float) -> str | None:
    """One key press within `timeout_s` (None: none, or no terminal to read from)."""
    if fd is None:
        time.sleep(timeout_s)
        return None
    ready, _, _ = select.select([fd], [], [], timeout_s)
    if not ready:
        return None
    data = os.read(fd, 32)
    if not data:
        return None
    # Several keys at once (pasted, or typed while drawing): an e-stop among them wins.
    text = data.decode(errors="replace")
    for k in ("e", "E", " "):
        if k in text:
            return k
    return text[-1]


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `monitor`."""
    from controller.cli.session import add_connection_arguments

    p = sub.add_parser(
        "monitor",
        help="terminal dashboard: state, pose, axes, loop, bus; keys s stop, e e-stop, q quit",
    )
    add_connection_arguments(p)
    p.add_argument(
        "--refresh", type=float, default=5.0, metavar="HZ", help="redraws a second (default 5)"
    )
    p.set_defaults(func=cmd_monitor)
