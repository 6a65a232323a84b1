"""Client CLI verbs that talk to a running daemon over Zenoh.

`cablebot list|pose|status|move|path|stop|estop|arm|disarm|reset|home`, connecting to
`tcp/127.0.0.1:7447` by default (`--connect ENDPOINT` or `HOST:PORT`, `--prefix PREFIX`).
The connection (session, queries, errors, options) is `controller.cli.session`; what the verbs
print is `controller.cli.formats`.

Exit codes: `controller.cli.exitcodes` (0 done; 1 refused or invalid input, the reason printed;
2 usage; 3 no daemon answered; 4 `--wait` timed out; 130 Ctrl-C).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import Any

from controller.cli import add_xyz_arguments, exitcodes, xyz_from_args
from controller.cli.formats import (
    PROGRESS_PERIOD_S,
    SeqGaps,
    StatusLine,
    axis_fault_text,
    axis_state_text,
    format_daemons,
    format_home,
    format_pose,
    format_pretension_result,
    format_reply,
    format_status,
    format_xyz,
    is_tty,
    path_remaining_m,
    status_tensions_n,
)
from controller.cli.pathcheck import PathFile, check_with_robot
from controller.cli.session import (
    DEFAULT_ENDPOINT,
    DEFAULT_PREFIX,
    LIVELINESS_TIMEOUT_S,
    DaemonAbsent,
    Failed,
    InputError,
    Refused,
    UsageError,
    WaitTimeout,
    add_connection_arguments,
    clean_zenoh_error,
    live_prefixes,
    normalize_endpoint,
    open_session,
    positive_count,
    query,
    run_with_session,
)
from controller.core.commands import MAX_PATH_POINTS_SENT
from controller.core.motion import MIN_SPEED_MPS, check_speed

# What moved to `session` (the connection) and `formats` (what is printed) is still importable
# from here.
__all__ = [
    "ARMED_STATES",
    "ARRIVED_TOL_M",
    "DEFAULT_ENDPOINT",
    "DEFAULT_POSE_RATE_HZ",
    "DEFAULT_PREFIX",
    "DETACH_TEXT",
    "EXIT_ABSENT",
    "EXIT_OK",
    "EXIT_REFUSED",
    "EXIT_USAGE",
    "EXIT_WAIT_TIMEOUT",
    "INTERRUPT_STOP_TEXT",
    "LIVELINESS_TIMEOUT_S",
    "PRETENSION_POLL_S",
    "PROGRESS_PERIOD_S",
    "DaemonAbsent",
    "Failed",
    "InputError",
    "Refused",
    "SeqGaps",
    "StatusLine",
    "UsageError",
    "WaitTimeout",
    "add_connection_arguments",
    "axis_fault_text",
    "axis_state_text",
    "clean_zenoh_error",
    "cmd_home",
    "cmd_list",
    "cmd_move",
    "cmd_path",
    "cmd_pose",
    "cmd_simple",
    "cmd_status",
    "format_daemons",
    "format_home",
    "format_pose",
    "format_pretension_result",
    "format_reply",
    "format_status",
    "list_daemons",
    "live_prefixes",
    "load_path_file",
    "normalize_endpoint",
    "open_session",
    "path_remaining_m",
    "query",
    "register",
    "run_with_session",
    "status_tensions_n",
]

EXIT_OK = exitcodes.OK
EXIT_REFUSED = exitcodes.REFUSED
EXIT_USAGE = exitcodes.USAGE
EXIT_ABSENT = exitcodes.NO_DAEMON
EXIT_WAIT_TIMEOUT = exitcodes.WAIT_TIMEOUT

ARRIVED_TOL_M = 1e-3
DEFAULT_POSE_RATE_HZ = 5.0

_run = run_with_session


# --------------------------------------------------------------------------------------------
# Verbs


def _robot_precheck(
    args: argparse.Namespace, speed: float | None, path: PathFile | None
) -> Callable[[Any], None]:
    """`pathcheck.check_with_robot` for this verb's arguments."""
    what = "--speed" if args.speed is not None else f"{getattr(args, 'file', '')}: speed_mps"
    return lambda session: check_with_robot(
        session, args.prefix, args.timeout, speed, path, speed_option=what
    )


def _vec3(values: Sequence[float], what: str) -> list[float]:
    out = [float(v) for v in values]
    if len(out) != 3 or not all(math.isfinite(v) for v in out):
        raise InputError(f"{what}: expected three finite numbers, got {values}")
    return out


def _speed(v: float | None) -> float | None:
    reason = None if v is None else check_speed(v)
    if reason is not None:
        raise InputError(f"--speed {reason}")
    return v


def load_path_file(path: str, *, stream: bool = False) -> dict[str, Any]:
    """Read a path file: JSON (a list of [x, y, z] or {"points_m": ..., "speed_mps": ...}) or
    CSV/whitespace lines `x,y,z` (`#` comments and a header line are skipped).

    Returns the `path` command payload. With `stream`, a file of any length (sent as a path
    and appended chunks: every chunk is checked as the command it becomes); without, at most
    the points one command carries. Raises InputError for an unreadable, not UTF-8 or invalid
    file.
    """
    return read_path_file(path, stream=stream)[0]


def read_path_file(path: str, *, stream: bool = False) -> tuple[dict[str, Any], list[int] | None]:
    """`load_path_file`, and the file's line number of every point (None for JSON, whose
    points are named by their position). Raises as `load_path_file` does."""
    from controller.service.textfile import NotUtf8Error, read_text

    try:
        text = read_text(path)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from None
    except NotUtf8Error as exc:
        raise InputError(f"{path}: {exc}") from None
    stripped = text.lstrip()
    payload: dict[str, Any]
    line_of: list[int] | None = None
    if stripped.startswith(("[", "{")):
        try:
            data = json.loads(text, parse_constant=_no_constant)
        except ValueError as exc:
            raise InputError(f"{path}: invalid JSON: {exc}") from None
        if isinstance(data, list):
            payload = {"points_m": data}
        elif isinstance(data, dict):
            payload = dict(data)
        else:
            raise InputError(f"{path}: expected a list of points or an object")
    else:
        points: list[list[float]] = []
        line_of = []
        header_seen = False
        rows = csv.reader(io.StringIO(text.replace("\t", ",")))
        for n, row in enumerate(rows, start=1):
            cells = [c for part in row for c in part.split()]
            if not cells or cells[0].startswith("#"):
                continue
            try:
                values = [float(c) for c in cells]
            except ValueError:
                if not points and not header_seen:
                    header_seen = True  # a header line such as "x,y,z"
                    continue
                raise InputError(f"{path} line {n}: expected x,y,z, got {row}") from None
            points.append(_vec3(values, f"{path} line {n}"))
            line_of.append(n)
        payload = {"points_m": points}
    from controller.core.commands import CommandError, parse_command

    pts = payload.get("points_m")
    if isinstance(pts, list) and len(pts) > MAX_PATH_POINTS_SENT and not stream:
        raise InputError(
            f"{path}: {len(pts)} points; one path command takes at most {MAX_PATH_POINTS_SENT}"
            f" points: split it into parts of at most {MAX_PATH_POINTS_SENT} points and send"
            " each with its own path command"
        )
    parts = [payload]
    if isinstance(pts, list) and len(pts) > MAX_PATH_POINTS_SENT:
        rest = {k: v for k, v in payload.items() if k != "points_m"}
        parts = [
            {**rest, "points_m": pts[i : i + MAX_PATH_POINTS_SENT]}
            for i in range(0, len(pts), MAX_PATH_POINTS_SENT)
        ]
    for i, part in enumerate(parts):
        try:
            parse_command("path", json.dumps(part))
        except (CommandError, ValueError) as exc:
            where = f" (points {i * MAX_PATH_POINTS_SENT} on)" if i else ""
            raise InputError(f"{path}{where}: {exc}") from None
    return payload, line_of


def _no_constant(name: str) -> Any:
    raise ValueError(f"non-finite number {name}")


def _key(args: argparse.Namespace, suffix: str) -> str:
    return f"{args.prefix.rstrip('/')}/{suffix}"


def _command(args: argparse.Namespace, verb: str, payload: dict[str, Any] | None) -> int:
    def body(session: Any) -> int:
        reply = query(session, _key(args, f"cmd/{verb}"), payload, args.timeout)
        _print_reply(verb, reply, args)
        return EXIT_OK

    return _run(args, body)


def _print_reply(verb: str, reply: Any, args: argparse.Namespace) -> None:
    if getattr(args, "json", False):
        print(json.dumps(reply), flush=True)
    else:
        print(format_reply(verb, reply), flush=True)


ARMED_STATES = frozenset({"ARMING", "HOLDING", "MOVING", "PRETENSIONING"})
"""States in which the motors are armed (or arming): `arm` there is already done."""


def cmd_simple(args: argparse.Namespace) -> int:
    """stop, estop, arm, disarm, reset: send the verb, print the reply. `arm` on a robot that
    is already armed succeeds, saying so."""
    verb: str = args.command
    if verb != "arm":
        return _command(args, verb, None)

    def body(session: Any) -> int:
        try:
            reply = query(session, _key(args, "cmd/arm"), None, args.timeout)
        except Refused:
            st = query(session, _key(args, "status"), None, args.timeout)
            state = st.get("state") if isinstance(st, dict) else None
            if state not in ARMED_STATES:
                raise
            if getattr(args, "json", False):
                print(json.dumps({"ok": True, "state": state, "already_armed": True}), flush=True)
            else:
                print(f"arm: already armed, state {state}", flush=True)
            return EXIT_OK
        _print_reply(verb, reply, args)
        if isinstance(reply, dict) and reply.get("state") == "ARMING":
            _follow_arming(session, args)
        return EXIT_OK

    return _run(args, body)


ARM_FOLLOW_S = 10.0
"""How long `arm` follows the arming (the daemon's own arming limit ends it sooner)."""
ARM_POLL_S = 0.1
"""How often `arm` asks the daemon how the arming goes."""


def _follow_arming(session: Any, args: argparse.Namespace) -> None:
    """After an accepted arm, follow the status until the arming ends. Returns when the robot
    is armed (or still arming after `ARM_FOLLOW_S`: the daemon goes on); raises Failed when
    the arming ended in FAULT, ESTOPPED or DISARMED, DaemonAbsent when the daemon is gone."""
    deadline = time.monotonic() + max(ARM_FOLLOW_S, args.timeout)
    while time.monotonic() < deadline:
        st = query(session, _key(args, "status"), None, args.timeout)
        state = st.get("state") if isinstance(st, dict) else None
        if state in ("FAULT", "ESTOPPED", "DISARMED"):
            raise Failed(f"the arming ended in {state}: {st.get('reason')}")
        if state != "ARMING":
            return
        time.sleep(ARM_POLL_S)


def cmd_home(args: argparse.Namespace) -> int:
    """home X Y Z [--pretension]: declare the effector's current position (after pulling every
    cable taut in torque control, with --pretension)."""
    try:
        payload = {"position_m": _vec3(xyz_from_args(args), "home")}
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    if args.pretension:
        return _pretension(args, payload)
    return _command(args, "home", payload)


PRETENSION_POLL_S = 0.2
"""How often `home --pretension` asks the daemon how the pre-tension goes."""


def _pretension(args: argparse.Namespace, payload: dict[str, Any]) -> int:
    """Start the pre-tension, then follow the daemon's status until it ends: the home pose
    declared (HOLDING), or the reason it did not. Raises Refused (Failed when the pre-tension
    ended in FAULT or another state without homing), WaitTimeout, DaemonAbsent."""

    def body(session: Any) -> int:
        reply = query(session, _key(args, "cmd/pretension"), payload, args.timeout)
        _print_reply("pretension", reply, args)
        line = StatusLine(sys.stdout, enabled=is_tty(sys.stdout) and not args.json)
        t0 = time.monotonic()
        try:
            while True:
                st = query(session, _key(args, "status"), None, args.timeout)
                if not isinstance(st, dict):
                    raise Refused(f"unexpected status reply {st!r}")
                state = st.get("state")
                pt = st.get("pretension") or {}
                result = pt.get("result")
                if state != "PRETENSIONING":
                    line.clear()
                    if state == "HOLDING" and isinstance(result, dict) and result.get("ok"):
                        if args.json:
                            print(json.dumps(result), flush=True)
                        else:
                            print(format_pretension_result(result), flush=True)
                        return EXIT_OK
                    raise Failed(f"the pre-tension ended in {state}: {st.get('reason')}")
                now = time.monotonic()
                if now - t0 > args.wait_timeout:
                    raise WaitTimeout(
                        f"still pretensioning after {args.wait_timeout:g} s (the daemon goes on)"
                    )
                fastest = pt.get("fastest_cable_mps")
                speed = "" if fastest is None else f", fastest cable {fastest * 1e3:.1f} mm/s"
                line.show(f"pretension: {now - t0:.1f} s{speed}", now)
                time.sleep(PRETENSION_POLL_S)
        finally:
            line.clear()

    return _run(args, body)


def _bad_wait_timeout(args: argparse.Namespace) -> bool:
    """True (and the reason printed) when `--wait-timeout` is not a number of seconds > 0."""
    if math.isfinite(args.wait_timeout) and args.wait_timeout > 0.0:
        return False
    print(
        f"cablebot {args.command}: --wait-timeout must be a number of seconds > 0,"
        f" got {args.wait_timeout:g}",
        file=sys.stderr,
    )
    return True


def cmd_move(args: argparse.Namespace) -> int:
    """move X Y Z [--speed V] [--wait]: command a straight move (and follow it)."""
    if _bad_wait_timeout(args):
        return EXIT_USAGE
    try:
        target = _vec3(xyz_from_args(args), "move")
        payload: dict[str, Any] = {"position_m": target}
        speed = _speed(args.speed)
        if speed is not None:
            payload["speed_mps"] = speed
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    precheck = None if speed is None else _robot_precheck(args, speed, None)
    return _motion(args, "move", payload, [target], precheck)


def cmd_path(args: argparse.Namespace) -> int:
    """path FILE [--speed V] [--wait]: command a multi-point path; a file longer than one
    command carries is streamed (`controller.cli.pathstream`)."""
    if _bad_wait_timeout(args):
        return EXIT_USAGE
    try:
        payload, line_of = read_path_file(args.file, stream=True)
        speed = _speed(args.speed)
        if speed is not None:
            payload["speed_mps"] = speed
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    points = [[float(v) for v in p] for p in payload["points_m"]]
    append = payload.get("append") is True
    sent_speed = payload.get("speed_mps")
    precheck = _robot_precheck(
        args,
        sent_speed if isinstance(sent_speed, int | float) else None,
        PathFile(args.file, points, line_of, append),
    )
    if len(points) > MAX_PATH_POINTS_SENT:
        return _stream_path(args, sent_speed, points, append=append, precheck=precheck)
    return _motion(args, "path", payload, points, precheck)


def _stream_path(
    args: argparse.Namespace,
    speed: float | None,
    points: list[list[float]],
    *,
    append: bool = False,
    precheck: Callable[[Any], None] | None = None,
) -> int:
    """Stream a long path (`pathstream.stream_points`), then with --wait follow it to its end
    as `_motion` does; Ctrl-C brakes to a hold (`_interrupted`). With `append` (the file's
    `"append": true`) the first chunk too is appended to the path in progress."""
    from controller.cli.pathstream import StreamRefused, stream_points

    def body(session: Any) -> int:
        if precheck is not None:
            precheck(session)
        poses: queue.SimpleQueue[bytes] = queue.SimpleQueue()  # see `_wait_arrival`
        sub = None
        if args.wait:
            sub = session.declare_subscriber(
                _key(args, "pose"), lambda s: poses.put(s.payload.to_bytes())
            )
        line = StatusLine(sys.stdout, enabled=is_tty(sys.stdout) and not args.json)

        def send(pts: list[list[float]], more: bool) -> dict[str, Any]:
            payload: dict[str, Any] = {"points_m": pts, "append": more or append}
            if speed is not None:
                payload["speed_mps"] = speed
            reply: dict[str, Any] = query(session, _key(args, "cmd/path"), payload, args.timeout)
            return reply

        def status() -> dict[str, Any]:
            st = query(session, _key(args, "status"), None, args.timeout)
            return st if isinstance(st, dict) else {}

        def drain() -> None:  # poses from before the last chunk never count as arrival
            with suppress(queue.Empty):
                while True:
                    poses.get_nowait()

        t0 = time.monotonic()
        try:
            with signals_interrupt(_waits_for_motion(args)):
                return _stream(send, status, drain, line, poses, t0)
        except KeyboardInterrupt:
            line.clear()
            return _interrupted(session, args)
        finally:
            if sub is not None:
                sub.undeclare()

    def _stream(
        send: Any,
        status: Any,
        drain: Any,
        line: StatusLine,
        poses: queue.SimpleQueue[bytes],
        t0: float,
    ) -> int:
        try:
            prog = stream_points(
                points,
                send,
                status,
                line.show,
                refused=Refused,
                before_last=drain,
                append_first=append,
            )
        except StreamRefused as exc:
            line.clear()
            raise Refused(str(exc)) from None
        line.clear()
        summary = {
            "points": prog.sent,
            "commands": prog.commands,
            "retries": prog.retries,
            "queued_points": prog.queued_points,
            "queued_s": prog.queued_s,
            "elapsed_s": time.monotonic() - t0,
        }
        if args.json:
            print(json.dumps({"ok": True, "streamed": summary}), flush=True)
        else:
            print(
                f"path: {prog.sent} points sent in {prog.commands} commands "
                f"({summary['elapsed_s']:.1f} s); {prog.queued_points} queued",
                flush=True,
            )
        if not args.wait:
            return EXIT_OK
        moving = status().get("state") == "MOVING"
        tail = points[-MAX_PATH_POINTS_SENT:]
        return _wait_arrival(args, "path", poses, tail, seen_moving=not moving, status=status)

    return _run(args, body)


def _motion(
    args: argparse.Namespace,
    verb: str,
    payload: dict[str, Any],
    points: list[list[float]],
    precheck: Callable[[Any], None] | None = None,
) -> int:
    def body(session: Any) -> int:
        if precheck is not None:
            precheck(session)
        poses: queue.SimpleQueue[bytes] = queue.SimpleQueue()  # see `_wait_arrival`
        sub = None
        if args.wait:  # subscribe first so no sample after the reply is missed
            sub = session.declare_subscriber(
                _key(args, "pose"), lambda s: poses.put(s.payload.to_bytes())
            )
        try:
            with signals_interrupt(_waits_for_motion(args)):
                return _send_and_wait(session, poses)
        except KeyboardInterrupt:
            return _interrupted(session, args)
        finally:
            if sub is not None:
                sub.undeclare()

    def _send_and_wait(session: Any, poses: queue.SimpleQueue[bytes]) -> int:
        reply = query(session, _key(args, f"cmd/{verb}"), payload, args.timeout)
        _print_reply(verb, reply, args)
        if not args.wait:
            return EXIT_OK
        # The daemon replies once the motion has started (MOVING). Poses published before it
        # took the command may already be in the queue, HOLDING where a path also ends: they
        # must not count as arrival. Unless the motion is already over, wait to see it move.
        status = query(session, _key(args, "status"), None, args.timeout)
        moving = isinstance(status, dict) and status.get("state") == "MOVING"
        return _wait_arrival(
            args,
            verb,
            poses,
            points,
            seen_moving=not moving,
            status=lambda: query(session, _key(args, "status"), None, args.timeout),
        )

    return _run(args, body)


WAIT_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)
)
"""Signals that, while a motion is waited on, count as Ctrl-C (the terminal closed, `kill`)."""


def _raise_interrupt(signum: int, frame: Any) -> None:
    raise KeyboardInterrupt


@contextmanager
def signals_interrupt(enabled: bool = True) -> Iterator[None]:
    """Within the block SIGTERM and SIGHUP raise KeyboardInterrupt (as Ctrl-C does), so a
    waited-on motion is stopped however the CLI is ended; the previous handlers come back
    after. A no-op when not `enabled` or off the main thread. Raises nothing itself."""
    if not enabled or threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {sig: signal.signal(sig, _raise_interrupt) for sig in WAIT_SIGNALS}
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _waits_for_motion(args: argparse.Namespace) -> bool:
    return bool(getattr(args, "wait", False)) and not getattr(args, "detach", False)


INTERRUPT_STOP_TEXT = "interrupted: braking to a hold"
DETACH_TEXT = "interrupted: detached; the robot goes on with the motion"


def _interrupted(session: Any, args: argparse.Namespace) -> int:
    """Ctrl-C while a motion command runs: send `stop` (brake to a hold) and say so, unless
    `--detach` was given (then only say that the motion goes on). Returns the exit code 130;
    a stop the daemon does not take is printed as such (exit 1 or 3)."""
    if getattr(args, "detach", False):
        print(DETACH_TEXT, file=sys.stderr, flush=True)
        return exitcodes.INTERRUPTED
    print(INTERRUPT_STOP_TEXT, file=sys.stderr, flush=True)
    try:
        reply = query(session, _key(args, "cmd/stop"), None, args.timeout)
    except Refused as exc:
        print(f"cablebot: stop refused: {exc}", file=sys.stderr, flush=True)
        return EXIT_REFUSED
    except DaemonAbsent as exc:
        print(f"cablebot: stop not confirmed: {exc}", file=sys.stderr, flush=True)
        return EXIT_ABSENT
    if getattr(args, "json", False):
        print(json.dumps(reply), flush=True)
    else:
        print(format_reply("stop", reply), flush=True)
    return exitcodes.INTERRUPTED


def _wait_arrival(
    args: argparse.Namespace,
    verb: str,
    poses: queue.SimpleQueue[bytes],
    points: list[list[float]],
    *,
    seen_moving: bool = True,
    status: Callable[[], Any] | None = None,
) -> int:
    """Follow the pose until it is within 1 mm of the last point in a still state (HOLDING).

    With `seen_moving` False, HOLDING samples count only after a MOVING one (the motion was
    still running when the wait began, and older samples may stand where the path ends).
    When the robot holds away from the end, `status()` (the daemon's status) says whether it
    is settling there (its set-point is the end) or the motion ended elsewhere: stopped by
    another client's `stop`, or replaced by another command (Failed at once, with the reason).

    On a terminal (and without `--json`) one line shows the distance still to travel, rewritten
    in place. At the end it prints "arrived: <pose>" (with `--json` a line
    `{"arrived": true, "pose": <the pose sample>}`). Raises WaitTimeout, Failed (the robot
    left the motion states, or the motion ended short of its end) or DaemonAbsent.
    """
    end = points[-1]
    line = StatusLine(sys.stdout, enabled=is_tty(sys.stdout) and not args.json)
    t0 = time.monotonic()
    deadline = t0 + args.wait_timeout
    last_rx = t0
    last: dict[str, Any] | None = None
    legs: list[tuple[list[float], list[float]]] | None = None
    leg = 0
    asked = False  # the status was asked during this hold (settling, or ended elsewhere)
    try:
        while True:
            now = time.monotonic()
            if now >= deadline:
                where = "" if last is None else f"; last {format_pose(last)}"
                raise WaitTimeout(
                    f"not at the target after {args.wait_timeout:g} s{where}; the robot goes on"
                    " with the motion (`cablebot stop` stops it)"
                )
            try:
                # A SimpleQueue: Ctrl-C landing while `queue.Queue`'s condition re-takes its
                # lock turned KeyboardInterrupt into "RuntimeError: release unlocked lock" (a
                # traceback instead of braking); SimpleQueue's wait is interrupted cleanly.
                data = poses.get(timeout=min(0.5, deadline - now))
            except queue.Empty:
                if time.monotonic() - last_rx > args.timeout:
                    raise DaemonAbsent(f"no pose sample for {args.timeout:g} s") from None
                continue
            last_rx = time.monotonic()
            last = json.loads(data)
            state = str(last.get("state"))
            if state in ("FAULT", "ESTOPPED", "DISARMED"):
                raise Failed(f"the robot went {state} during the motion: {format_pose(last)}")
            pos = last.get("position_m")
            if pos is None:
                continue
            if state == "MOVING":
                seen_moving = True
                asked = False
            if state == "HOLDING" and seen_moving and math.dist(pos, end) <= ARRIVED_TOL_M:
                line.clear()
                if args.json:
                    print(json.dumps({"arrived": True, "pose": last}), flush=True)
                else:
                    print(f"arrived: {format_pose(last)}", flush=True)
                return EXIT_OK
            if state == "HOLDING" and seen_moving and status is not None and not asked:
                asked = True
                _check_held_for(status(), end, last)
            if legs is None:
                starts = [list(pos), *points[:-1]]
                legs = list(zip(starts, points, strict=True))
            leg, remaining = path_remaining_m(legs, pos, leg)
            line.show(
                f"{verb}: {remaining:.3f} m to go  {state}  {format_xyz(pos)}"
                f"  {last_rx - t0:.1f} s",
                last_rx,
            )
    finally:
        line.clear()


def _check_held_for(st: Any, end: Sequence[float], last: dict[str, Any]) -> None:
    """Raise Failed when the status `st` holds a set-point away from `end`: the motion waited
    on ended there (stopped, or replaced by another command), not at its end."""
    if not isinstance(st, dict) or st.get("state") != "HOLDING":
        return
    sp = st.get("setpoint_m")
    if not isinstance(sp, list) or len(sp) != 3 or math.dist(sp, end) <= ARRIVED_TOL_M:
        return  # settling on the end point
    why = st.get("reason") or "another command took over"
    pos = last.get("position_m") or sp
    raise Failed(
        f"the motion ended {math.dist(pos, end):.3f} m short of {format_xyz(end)}: {why}; "
        f"{format_pose(last)}"
    )


def list_daemons(session: Any, timeout_s: float) -> list[dict[str, Any]]:
    """Every live daemon on the session's network: prefix, robot name, state and the endpoints
    it listens on (from its status; None where it did not answer within `timeout_s`)."""
    out: list[dict[str, Any]] = []
    for prefix in live_prefixes(session):
        row: dict[str, Any] = {"prefix": prefix, "name": None, "state": None, "listen": None}
        try:
            st = query(session, f"{prefix}/status", None, timeout_s)
        except (DaemonAbsent, Refused, ValueError):
            st = None
        if isinstance(st, dict):
            cfg = st.get("config")
            z = st.get("zenoh")
            row["name"] = cfg.get("name") if isinstance(cfg, dict) else None
            row["state"] = st.get("state")
            row["listen"] = z.get("listen") if isinstance(z, dict) else None
        out.append(row)
    return out


def cmd_list(args: argparse.Namespace) -> int:
    """list [--json]: every live daemon reachable via `--connect` (prefix, name, state,
    endpoint); exit 3 when there is none."""

    def body(session: Any) -> int:
        rows = list_daemons(session, args.timeout)
        if not rows:
            print(f"cablebot: no live cablebot daemon via {args.connect}", file=sys.stderr)
            return EXIT_ABSENT
        print(json.dumps(rows) if args.json else format_daemons(rows), flush=True)
        return EXIT_OK

    return _run(args, body)


def cmd_status(args: argparse.Namespace) -> int:
    """status [--json]: print the daemon's status."""

    def body(session: Any) -> int:
        st = query(session, _key(args, "status"), None, args.timeout)
        print(json.dumps(st, indent=2) if args.json else format_status(st), flush=True)
        return EXIT_OK

    return _run(args, body)


def cmd_pose(args: argparse.Namespace) -> int:
    """pose [--count N] [--rate HZ] [--json]: follow the pose until N lines (or Ctrl-C).

    Human lines come at most `--rate` times a second (default 5; a state change is shown at
    once); `--json` prints every sample unless `--rate` is given. Samples missed in between
    (gaps in `seq`) are reported: a line "gap: N samples missed" (on stderr with `--json`).
    """
    rate_hz = args.rate
    if rate_hz is None:
        rate_hz = 0.0 if args.json else DEFAULT_POSE_RATE_HZ
    if not math.isfinite(rate_hz) or rate_hz < 0.0:
        print(
            f"cablebot: --rate must be a number >= 0 (0: every sample), got {rate_hz}",
            file=sys.stderr,
        )
        return EXIT_USAGE
    min_interval_s = 0.0 if rate_hz == 0.0 else 1.0 / rate_hz

    def body(session: Any) -> int:
        poses: queue.Queue[bytes] = queue.Queue(maxsize=10_000)

        def on_sample(s: Any) -> None:
            with suppress(queue.Full):
                poses.put_nowait(s.payload.to_bytes())

        gaps = SeqGaps()
        sub = session.declare_subscriber(_key(args, "pose"), on_sample)
        ended = False
        try:
            printed = 0
            unreported = 0
            next_s = 0.0
            last_state: Any = None
            while args.count is None or printed < args.count:
                try:
                    data = poses.get(timeout=args.timeout)
                except queue.Empty:
                    raise DaemonAbsent(f"no pose sample within {args.timeout:g} s") from None
                sample = json.loads(data)
                unreported += gaps.update(sample.get("seq"))
                now = time.monotonic()
                state = sample.get("state")
                if now < next_s and state == last_state:
                    continue
                next_s = now + min_interval_s
                last_state = state
                if unreported:
                    print(
                        f"gap: {unreported} samples missed",
                        file=sys.stderr if args.json else sys.stdout,
                        flush=True,
                    )
                    unreported = 0
                print(data.decode() if args.json else format_pose(sample), flush=True)
                printed += 1
            ended = True
        except KeyboardInterrupt:
            ended = True
            raise
        finally:
            sub.undeclare()
            # Not after a failure (a closed pipe, no daemon): that has its own message.
            if ended and gaps.missed:
                print(
                    f"pose: {gaps.received} samples received, {gaps.missed} missed",
                    file=sys.stderr,
                    flush=True,
                )
        return EXIT_OK

    return _run(args, body)


# --------------------------------------------------------------------------------------------
# Registration


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register pose, status, move, path, stop, estop, arm, disarm, reset, home."""
    p = sub.add_parser("pose", help="follow the published pose")
    add_connection_arguments(p)
    p.add_argument(
        "--count", type=positive_count, default=None, metavar="N", help="stop after N lines"
    )
    p.add_argument(
        "--rate",
        type=float,
        default=None,
        metavar="HZ",
        help=(
            f"at most HZ lines a second (default {DEFAULT_POSE_RATE_HZ:g}; with --json every"
            " sample); 0: every sample"
        ),
    )
    p.add_argument("--json", action="store_true", help="print the raw JSON samples")
    p.set_defaults(func=cmd_pose)

    p = sub.add_parser(
        "list",
        help="list every live daemon (prefix, name, state, endpoint)",
        description=(
            "List the cablebot daemons alive on the Zenoh network reached via --connect (each "
            "declares the liveliness token <prefix>/alive): their prefix (give it as --prefix "
            "to the other verbs), robot name, state and listen endpoints."
        ),
    )
    add_connection_arguments(p)
    p.add_argument("--json", action="store_true", help="print a JSON list")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("status", help="print the daemon's status")
    add_connection_arguments(p)
    p.add_argument("--json", action="store_true", help="print the raw JSON status")
    p.set_defaults(func=cmd_status)

    for verb, what in (("move", "move in a straight line to X Y Z"), ("path", "follow a path")):
        p = sub.add_parser(
            verb,
            help=what,
            description=(
                f"{what[0].upper()}{what[1:]}. With --wait, Ctrl-C stops the robot: the CLI sends"
                " stop (it brakes to a hold) and prints 'interrupted: braking to a hold'; with"
                " --detach, Ctrl-C only stops waiting and the motion goes on."
            ),
        )
        add_connection_arguments(p)
        if verb == "move":
            add_xyz_arguments(p)
        else:
            p.add_argument(
                "file",
                metavar="FILE",
                help=(
                    "JSON points or CSV x,y,z lines, any number: beyond one command's "
                    f"{MAX_PATH_POINTS_SENT} points the rest is streamed as appends while the "
                    "robot flies"
                ),
            )
        p.add_argument(
            "--speed",
            type=float,
            default=None,
            metavar="V",
            help=(
                f"speed in m/s, at least {MIN_SPEED_MPS:g} and at most the robot's"
                " limits.max_speed_mps (a higher one is refused)"
            ),
        )
        p.add_argument(
            "--wait",
            action="store_true",
            help=(
                "wait until the end point is reached; Ctrl-C while waiting stops the robot "
                "(sends stop: it brakes to a hold) unless --detach is given"
            ),
        )
        p.add_argument(
            "--detach",
            action="store_true",
            help="with --wait: Ctrl-C only stops waiting and leaves the robot moving",
        )
        p.add_argument(
            "--wait-timeout",
            type=float,
            default=120.0,
            metavar="S",
            help="give up waiting after S seconds (default 120)",
        )
        p.add_argument("--json", action="store_true", help="print the raw JSON reply")
        p.set_defaults(func=cmd_move if verb == "move" else cmd_path)

    for verb, what in (
        ("stop", "decelerate to a hold"),
        ("estop", "emergency stop: disarm the motors at once"),
        ("arm", "arm the motors and hold the current pose"),
        ("disarm", "disarm the motors (support the load first)"),
        ("reset", "clear FAULT or ESTOPPED back to DISARMED"),
    ):
        p = sub.add_parser(verb, help=what)
        add_connection_arguments(p)
        p.add_argument("--json", action="store_true", help="print the raw JSON reply")
        p.set_defaults(func=cmd_simple)

    p = sub.add_parser("home", help="declare that the effector is now at X Y Z")
    add_connection_arguments(p)
    add_xyz_arguments(p)
    p.add_argument(
        "--pretension",
        action="store_true",
        help=(
            "first pull every cable in torque control with the tension that holds the payload "
            "at X Y Z until the reels are still, then home there (needs [payload])"
        ),
    )
    p.add_argument(
        "--wait-timeout",
        type=float,
        default=120.0,
        metavar="S",
        help="with --pretension: give up waiting after S seconds (default 120)",
    )
    p.add_argument("--json", action="store_true", help="print the raw JSON reply")
    p.set_defaults(func=cmd_home)
