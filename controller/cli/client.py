"""Client CLI verbs that talk to a running daemon over Zenoh.

`cablebot list|pose|status|move|path|stop|estop|arm|disarm|reset|home`, connecting to
`tcp/127.0.0.1:7447` by default (`--connect ENDPOINT` or `HOST:PORT`, `--prefix PREFIX`).
Each verb is the client library (`controller.client.Robot`) and what it prints: the options,
the session and the error handling are `controller.cli.session`; what the verbs print is
`controller.cli.formats`.

Exit codes: `controller.cli.exitcodes` (0 done; 1 refused or invalid input, the reason printed;
2 usage; 3 no daemon answered; 4 `--wait` timed out; 130 Ctrl-C).
"""

from __future__ import annotations

import argparse
import json
import math
import queue
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from controller.cli import add_xyz_arguments, exitcodes, pathstream, xyz_from_args
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
from controller.client import inputs
from controller.client.arrival import ARRIVED_TOL_M, Arrival, ArrivalProgress, follow_arrival
from controller.client.inputs import load_path_file, read_path_file
from controller.client.link import list_daemons
from controller.client.model import Pose, Reply, Status
from controller.client.pathcheck import PathFile, check_with_robot
from controller.client.robot import ARM_FOLLOW_S, ARMED_STATES, PRETENSION_POLL_S, Robot
from controller.client.signals import WAIT_SIGNALS, signals_interrupt
from controller.core.commands import MAX_PATH_POINTS_SENT
from controller.core.motion import MIN_SPEED_MPS, check_speed

# What moved to `session` (the connection), `formats` (what is printed) and the client
# library is still importable from here.
__all__ = [
    "ARMED_STATES",
    "ARM_FOLLOW_S",
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
    "WAIT_SIGNALS",
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
    "read_path_file",
    "register",
    "robot_of",
    "run_with_session",
    "signals_interrupt",
    "status_tensions_n",
]

EXIT_OK = exitcodes.OK
EXIT_REFUSED = exitcodes.REFUSED
EXIT_USAGE = exitcodes.USAGE
EXIT_ABSENT = exitcodes.NO_DAEMON
EXIT_WAIT_TIMEOUT = exitcodes.WAIT_TIMEOUT

DEFAULT_POSE_RATE_HZ = 5.0

_run = run_with_session


def _query(session: Any, key: str, payload: Any, timeout_s: float) -> Any:
    # Through this module's `query`, looked up at each call: a test stands in for the daemon
    # by replacing it.
    return query(session, key, payload, timeout_s)


def robot_of(
    args: argparse.Namespace, session: Any, query_fn: Callable[..., Any] = _query
) -> Robot:
    """The client library's Robot for a verb's `--prefix` and `--timeout`, on its session."""
    return Robot(session=session, prefix=args.prefix, timeout_s=args.timeout, query=query_fn)


# --------------------------------------------------------------------------------------------
# Verbs


def _robot_precheck(
    args: argparse.Namespace, speed: float | None, path: PathFile | None
) -> Callable[[Robot], None]:
    """`pathcheck.check_with_robot` for this verb's arguments."""
    what = "--speed" if args.speed is not None else f"{getattr(args, 'file', '')}: speed_mps"
    return lambda robot: check_with_robot(robot, speed, path, speed_option=what)


def _speed(v: float | None) -> float | None:
    reason = None if v is None else check_speed(v)
    if reason is not None:
        raise InputError(f"--speed {reason}")
    return v


def _print_reply(verb: str, reply: Reply, args: argparse.Namespace) -> None:
    if getattr(args, "json", False):
        print(json.dumps(dict(reply.raw)), flush=True)
    else:
        print(format_reply(verb, dict(reply.raw)), flush=True)


def _command(args: argparse.Namespace, verb: str, payload: dict[str, Any] | None) -> int:
    def body(session: Any) -> int:
        _print_reply(verb, robot_of(args, session).command(verb, payload), args)
        return EXIT_OK

    return _run(args, body)


def cmd_simple(args: argparse.Namespace) -> int:
    """stop, estop, arm, disarm, reset: send the verb, print the reply. `arm` on a robot that
    is already armed succeeds, saying so; an arming is followed until it ends."""
    verb: str = args.command
    if verb != "arm":
        return _command(args, verb, None)

    def body(session: Any) -> int:
        robot = robot_of(args, session)
        reply = robot.arm()
        if reply.already_armed:
            if getattr(args, "json", False):
                print(json.dumps(dict(reply.raw)), flush=True)
            else:
                print(f"arm: already armed, state {reply.state}", flush=True)
            return EXIT_OK
        _print_reply(verb, reply, args)
        if reply.state == "ARMING":
            robot.wait_armed(max(ARM_FOLLOW_S, args.timeout))
        return EXIT_OK

    return _run(args, body)


def cmd_home(args: argparse.Namespace) -> int:
    """home X Y Z [--pretension]: declare the effector's current position (after pulling every
    cable taut in torque control, with --pretension)."""
    try:
        payload = {"position_m": inputs.point(xyz_from_args(args), "home")}
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    if args.pretension:
        return _pretension(args, payload)
    return _command(args, "home", payload)


def _pretension(args: argparse.Namespace, payload: dict[str, Any]) -> int:
    """Start the pre-tension, then follow the daemon's status until it ends: the home pose
    declared (HOLDING), or the reason it did not. Raises Refused (Failed when the pre-tension
    ended in FAULT or another state without homing), WaitTimeout, DaemonAbsent."""

    def body(session: Any) -> int:
        robot = robot_of(args, session)
        _print_reply("pretension", robot.pretension(payload["position_m"]), args)
        line = StatusLine(sys.stdout, enabled=is_tty(sys.stdout) and not args.json)

        def show(st: Status, elapsed_s: float) -> None:
            fastest = st.pretension.fastest_cable_mps
            speed = "" if fastest is None else f", fastest cable {fastest * 1e3:.1f} mm/s"
            line.show(f"pretension: {elapsed_s:.1f} s{speed}", time.monotonic())

        try:
            result = robot.wait_pretension(args.wait_timeout, on_progress=show)
        finally:
            line.clear()
        if args.json:
            print(json.dumps(dict(result.raw)), flush=True)
        else:
            print(format_pretension_result(dict(result.raw)), flush=True)
        return EXIT_OK

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
        target = inputs.point(xyz_from_args(args), "move")
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
    command carries is streamed (`_stream_path`)."""
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
    precheck: Callable[[Robot], None] | None = None,
) -> int:
    """Stream a long path (the library's `stream_points`, as `Robot.iter_path` does), then
    with --wait follow it to its end as `_motion` does; Ctrl-C, SIGTERM and SIGHUP brake to a
    hold (`_interrupted`) while it streams or is waited on, as for `gcode` (a path cut off
    where its sender died is not the path asked for), unless `--detach`. With `append` (the
    file's `"append": true`) the first chunk too is appended to the path in progress."""

    def body(session: Any) -> int:
        robot = robot_of(args, session)
        if precheck is not None:
            precheck(robot)
        line = StatusLine(sys.stdout, enabled=is_tty(sys.stdout) and not args.json)
        t0 = time.monotonic()
        try:
            with signals_interrupt(not getattr(args, "detach", False)):
                robot.expect_motion(points[-MAX_PATH_POINTS_SENT:])  # what --wait follows
                try:
                    prog = pathstream.stream_points(
                        points,
                        lambda pts, more: robot.path_chunk(
                            pts, speed_mps=speed, append=more or append
                        ),
                        robot.status_map,
                        line.show,
                        refused=Refused,
                        append_first=append,
                    )
                except pathstream.StreamRefused as exc:
                    raise Refused(str(exc)) from None
                finally:
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
                return _follow(args, "path", robot)
        except KeyboardInterrupt:
            line.clear()
            return _interrupted(robot, args)

    return _run(args, body)


def _motion(
    args: argparse.Namespace,
    verb: str,
    payload: dict[str, Any],
    points: list[list[float]],
    precheck: Callable[[Robot], None] | None = None,
) -> int:
    def body(session: Any) -> int:
        robot = robot_of(args, session)
        if precheck is not None:
            precheck(robot)
        try:
            with signals_interrupt(_waits_for_motion(args)):
                # With --wait the pose is followed from before the command goes: no sample
                # after the reply is missed.
                reply = robot.send_motion(verb, payload, points, follow=args.wait)
                _print_reply(verb, reply, args)
                if not args.wait:
                    return EXIT_OK
                return _follow(args, verb, robot)
        except KeyboardInterrupt:
            return _interrupted(robot, args)

    return _run(args, body)


def _follow(args: argparse.Namespace, verb: str, robot: Robot) -> int:
    """`--wait`: follow the motion the robot sent last to its end (`_wait_arrival`)."""
    samples, arrival = robot.arrival()
    return _wait_arrival(
        args,
        verb,
        samples,
        arrival.points,
        seen_moving=arrival.seen_moving,
        status=robot.status,
    )


def _waits_for_motion(args: argparse.Namespace) -> bool:
    return bool(getattr(args, "wait", False)) and not getattr(args, "detach", False)


INTERRUPT_STOP_TEXT = "interrupted: braking to a hold"
DETACH_TEXT = "interrupted: detached; the robot goes on with the motion"


def _interrupted(robot: Robot, args: argparse.Namespace) -> int:
    """Ctrl-C while a motion command runs: send `stop` (brake to a hold) and say so, unless
    `--detach` was given (then only say that the motion goes on). Returns the exit code 130;
    a stop the daemon does not take is printed as such (exit 1 or 3)."""
    if getattr(args, "detach", False):
        print(DETACH_TEXT, file=sys.stderr, flush=True)
        return exitcodes.INTERRUPTED
    print(INTERRUPT_STOP_TEXT, file=sys.stderr, flush=True)
    try:
        reply = robot.stop()
    except Refused as exc:
        print(f"cablebot: stop refused: {exc}", file=sys.stderr, flush=True)
        return EXIT_REFUSED
    except DaemonAbsent as exc:
        print(f"cablebot: stop not confirmed: {exc}", file=sys.stderr, flush=True)
        return EXIT_ABSENT
    _print_reply("stop", reply, args)
    return exitcodes.INTERRUPTED


def _as_status(st: Any) -> Status:
    return st if isinstance(st, Status) else Status.from_mapping(st if isinstance(st, dict) else {})


def _wait_arrival(
    args: argparse.Namespace,
    verb: str,
    poses: Any,
    points: Sequence[Sequence[float]],
    *,
    seen_moving: bool = True,
    status: Callable[[], Any] | None = None,
) -> int:
    """Follow the pose until it is within 1 mm of the last point in a still state (HOLDING):
    the library's rule (`controller.client.arrival`), fed from `poses` (anything with
    `get(timeout=...)`: a Robot's samples, or a queue of the daemon's JSON samples).

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
    line = StatusLine(sys.stdout, enabled=is_tty(sys.stdout) and not args.json)

    def next_pose(timeout_s: float) -> Pose | None:
        try:
            item = poses.get(timeout=timeout_s)
        except queue.Empty:
            return None
        if item is None or isinstance(item, Pose):
            return item
        try:
            return Pose.from_json(item)
        except ValueError:  # no daemon sends one; skipped as if it had not come
            return None

    def show(p: ArrivalProgress) -> None:
        line.show(
            f"{verb}: {p.remaining_m:.3f} m to go  {p.state}  {format_xyz(p.position_m)}"
            f"  {p.elapsed_s:.1f} s",
            p.pose.received_s,
        )

    try:
        pose = follow_arrival(
            next_pose,
            Arrival(points, seen_moving=seen_moving),
            wait_timeout_s=args.wait_timeout,
            sample_timeout_s=args.timeout,
            status=None if status is None else (lambda: _as_status(status())),
            on_progress=show,
        )
    finally:
        line.clear()
    sample = pose.as_dict()
    if args.json:
        print(json.dumps({"arrived": True, "pose": sample}), flush=True)
    else:
        print(f"arrived: {format_pose(sample)}", flush=True)
    return EXIT_OK


def cmd_list(args: argparse.Namespace) -> int:
    """list [--json]: every live daemon reachable via `--connect` (prefix, name, state,
    endpoint); exit 3 when there is none."""

    def body(session: Any) -> int:
        rows = [d.as_dict() for d in list_daemons(session, args.timeout, query=_query)]
        if not rows:
            print(f"cablebot: no live cablebot daemon via {args.connect}", file=sys.stderr)
            return EXIT_ABSENT
        print(json.dumps(rows) if args.json else format_daemons(rows), flush=True)
        return EXIT_OK

    return _run(args, body)


def cmd_status(args: argparse.Namespace) -> int:
    """status [--json]: print the daemon's status."""

    def body(session: Any) -> int:
        st = dict(robot_of(args, session).status().raw)
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
        gaps = SeqGaps()
        ended = False
        stream = robot_of(args, session).poses(timeout_s=args.timeout)
        try:
            printed = 0
            unreported = 0
            next_s = 0.0
            last_state: Any = None
            for pose in stream:
                unreported += gaps.update(pose.seq)
                now = time.monotonic()
                if now < next_s and pose.state == last_state:
                    continue
                next_s = now + min_interval_s
                last_state = pose.state
                if unreported:
                    print(
                        f"gap: {unreported} samples missed",
                        file=sys.stderr if args.json else sys.stdout,
                        flush=True,
                    )
                    unreported = 0
                print(pose.raw.decode() if args.json else format_pose(pose.as_dict()), flush=True)
                printed += 1
                if args.count is not None and printed >= args.count:
                    break
            ended = True
        except KeyboardInterrupt:
            ended = True
            raise
        finally:
            stream.close()
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
