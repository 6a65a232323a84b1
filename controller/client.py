"""Client CLI verbs that talk to a running daemon over Zenoh (issue 6).

`cablebot pose|status|move|path|stop|estop|arm|disarm|reset|home`, connecting to
`tcp/127.0.0.1:7447` by default (`--connect ENDPOINT`, `--prefix PREFIX`).

Exit codes: 0 done; 1 the daemon refused (the reason is printed) or the input is invalid;
2 no daemon answered (nothing listening, wrong prefix, or no reply in time).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import queue
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import Any

from controller.cli import add_xyz_arguments, xyz_from_args
from controller.motion import MIN_SPEED_MPS, check_speed

EXIT_OK = 0
EXIT_REFUSED = 1
EXIT_ABSENT = 2

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_PREFIX = "cablebot/default"
ARRIVED_TOL_M = 1e-3


class DaemonAbsent(RuntimeError):
    """No daemon answered: nothing listening on the endpoint, wrong prefix, or no reply in time."""


class Refused(RuntimeError):
    """The daemon answered with an error reply; the message is its reason."""


class InputError(ValueError):
    """The user's input (numbers, path file) is invalid; nothing was sent."""


# --------------------------------------------------------------------------------------------
# Session and queries


@contextmanager
def open_session(endpoint: str, *, config_file: str | None = None) -> Iterator[Any]:
    """Open a client-mode Zenoh session connected to `endpoint`; close it on exit.

    Raises DaemonAbsent when nothing accepts the connection (or the endpoint is invalid).
    """
    import zenoh

    from controller.zenoh_io import client_config

    try:
        session = zenoh.open(client_config([endpoint], config_file=config_file))
    except zenoh.ZError as exc:
        raise DaemonAbsent(f"cannot connect to {endpoint}: {_first_line(str(exc))}") from None
    try:
        yield session
    finally:
        session.close()  # type: ignore[no-untyped-call]


def _first_line(text: str) -> str:
    line = text.strip().splitlines()[0] if text.strip() else text
    return line.split("  at ")[0].strip()


def query(session: Any, key: str, payload: dict[str, Any] | None, timeout_s: float) -> Any:
    """Send one query to `key` with a JSON `payload`; return the decoded JSON reply.

    Raises Refused with the daemon's reason for an error reply, DaemonAbsent when no reply
    arrives within `timeout_s` (no queryable on that key, or a Zenoh timeout).
    """
    import zenoh

    body = None if payload is None else json.dumps(payload, allow_nan=False).encode()
    replies = session.get(
        key,
        payload=body,
        encoding=zenoh.Encoding.APPLICATION_JSON if body is not None else None,
        timeout=timeout_s,
    )
    for reply in replies:
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
        err = reply.err.payload.to_bytes().decode(errors="replace")
        try:
            decoded = json.loads(err)
        except ValueError:
            decoded = None
        if isinstance(decoded, dict) and "error" in decoded:
            raise Refused(str(decoded["error"]))
        if err.strip().lower() == "timeout":
            raise DaemonAbsent(f"no reply on {key} within {timeout_s:g} s")
        raise Refused(err)
    raise DaemonAbsent(f"no reply on {key}")


def _absent_message(args: argparse.Namespace, detail: str) -> str:
    return f"no cablebot daemon answered on {args.prefix} via {args.connect} ({detail})"


def _run(args: argparse.Namespace, body: Any) -> int:
    """Run `body(session)` with the CLI's error handling and exit codes."""
    try:
        with open_session(args.connect, config_file=args.zenoh_config) as session:
            code: int = body(session)
            return code
    except DaemonAbsent as exc:
        print(f"cablebot: {_absent_message(args, str(exc))}", file=sys.stderr)
        return EXIT_ABSENT
    except Refused as exc:
        print(f"cablebot: refused: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except KeyboardInterrupt:
        return 130


# --------------------------------------------------------------------------------------------
# Formatting


def format_pose(sample: dict[str, Any]) -> str:
    """One human-readable line for a pose sample."""
    pos = sample.get("position_m")
    if pos is None:
        where = "x=   ---  y=   ---  z=   ---  m (pose not valid)"
    else:
        where = f"x={pos[0]:+.3f} y={pos[1]:+.3f} z={pos[2]:+.3f} m"
    res = sample.get("residual_m")
    resid = "" if res is None else f"  resid {res * 1e3:.1f} mm"
    return f"seq {sample.get('seq')}  state {sample.get('state')}  {where}{resid}"


def format_status(st: dict[str, Any]) -> str:
    """A short multi-line summary of a status reply."""
    lines = [f"state      {st.get('state')}" + (f" ({st['reason']})" if st.get("reason") else "")]
    pose = st.get("pose") or {}
    if pose.get("position_m") is not None:
        x, y, z = pose["position_m"]
        lines.append(f"position   x={x:+.4f} y={y:+.4f} z={z:+.4f} m")
    else:
        lines.append("position   not valid")
    if "homed" in st:
        lines.append(f"homed      {st.get('homed')} ({st.get('home_source')})")
    for ax in st.get("axes", []):
        age = ax.get("age_s")
        age_s = "never" if age is None else f"{age * 1e3:.1f} ms ago"
        lines.append(
            f"axis {ax.get('node_id')}     state {ax.get('axis_state')}"
            f" error {ax.get('axis_error')}  reading {age_s}"
        )
    lp = st.get("loop")
    if lp:
        lines.append(
            f"loop       {lp.get('rate_hz')} Hz, ticks {lp.get('ticks')}, overruns"
            f" {lp.get('overruns')}, jitter p99 {_ms(lp.get('jitter_p99_s'))},"
            f" compute p99 {_ms(lp.get('compute_p99_s'))}"
        )
    bus = st.get("bus")
    if bus:
        lines.append(
            f"bus        rx {bus.get('frames_rx')} tx {bus.get('frames_tx')} errors"
            f" {bus.get('bus_errors')} decode errors {bus.get('decode_errors')}"
            f" dropped {bus.get('dropped')}"
        )
    z = st.get("zenoh")
    if z:
        put = z.get("pose_put") or {}
        tick = z.get("pose_publish_tick") or {}
        cmds = z.get("commands") or {}
        lines.append(
            f"zenoh      {z.get('mode')} {', '.join(z.get('listen') or [])}, prefix"
            f" {z.get('prefix')}; poses {z.get('poses_published')}, put p50/p99"
            f" {_us(put.get('p50_us'))}/{_us(put.get('p99_us'))}, tick cost p50/p99"
            f" {_us(tick.get('p50_us'))}/{_us(tick.get('p99_us'))}"
        )
        lines.append(
            "commands   "
            + ", ".join(f"{k} {v}" for k, v in cmds.items())
            + f"; set-points ok {(z.get('setpoints') or {}).get('ok')}"
            f" bad {(z.get('setpoints') or {}).get('bad')}"
        )
    cfg = st.get("config")
    if isinstance(cfg, dict) and "name" in cfg:
        loop_cfg = cfg.get("loop") or {}
        lines.append(
            f"config     robot {cfg.get('name')!r} from {cfg.get('source')},"
            f" {len(cfg.get('reels') or [])} reels, loop {loop_cfg.get('rate_hz')} Hz"
        )
    return "\n".join(lines)


def _ms(v: Any) -> str:
    return "-" if v is None else f"{float(v) * 1e3:.2f} ms"


def _us(v: Any) -> str:
    return "-" if v is None else f"{float(v):.0f} us"


# --------------------------------------------------------------------------------------------
# Verbs


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


def load_path_file(path: str) -> dict[str, Any]:
    """Read a path file: JSON (a list of [x, y, z] or {"points_m": ..., "speed_mps": ...}) or
    CSV/whitespace lines `x,y,z` (`#` comments and a header line are skipped).

    Returns the `path` command payload. Raises InputError for an unreadable or invalid file.
    """
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from None
    stripped = text.lstrip()
    payload: dict[str, Any]
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
        payload = {"points_m": points}
    from controller.commands import CommandError, parse_command

    try:
        parse_command("path", json.dumps(payload))
    except (CommandError, ValueError) as exc:
        raise InputError(f"{path}: {exc}") from None
    return payload


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
        print(json.dumps(reply))
        return
    extra = ""
    if isinstance(reply, dict):
        extra = " ".join(f"{k}={v}" for k, v in reply.items() if k != "ok")
    print(f"{verb}: ok {extra}".rstrip())
    limited = reply.get("speed_limited_to_mps") if isinstance(reply, dict) else None
    if isinstance(limited, int | float):
        print(f"{verb}: speed limited to {limited:g} m/s, the robot's maximum")


def cmd_simple(args: argparse.Namespace) -> int:
    """stop, estop, arm, disarm, reset: send the verb, print the reply."""
    verb: str = args.command
    return _command(args, verb, None)


def cmd_home(args: argparse.Namespace) -> int:
    """home X Y Z: declare the effector's current position."""
    try:
        payload = {"position_m": _vec3(xyz_from_args(args), "home")}
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    return _command(args, "home", payload)


def cmd_move(args: argparse.Namespace) -> int:
    """move X Y Z [--speed V] [--wait]: command a straight move (and follow it)."""
    try:
        target = _vec3(xyz_from_args(args), "move")
        payload: dict[str, Any] = {"position_m": target}
        speed = _speed(args.speed)
        if speed is not None:
            payload["speed_mps"] = speed
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    return _motion(args, "move", payload, target)


def cmd_path(args: argparse.Namespace) -> int:
    """path FILE [--speed V] [--wait]: command a multi-point path."""
    try:
        payload = load_path_file(args.file)
        speed = _speed(args.speed)
        if speed is not None:
            payload["speed_mps"] = speed
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    return _motion(args, "path", payload, list(payload["points_m"][-1]))


def _motion(args: argparse.Namespace, verb: str, payload: dict[str, Any], end: list[float]) -> int:
    def body(session: Any) -> int:
        poses: queue.Queue[bytes] = queue.Queue()
        sub = None
        if args.wait:  # subscribe first so no sample after the reply is missed
            sub = session.declare_subscriber(
                _key(args, "pose"), lambda s: poses.put(s.payload.to_bytes())
            )
        try:
            reply = query(session, _key(args, f"cmd/{verb}"), payload, args.timeout)
            _print_reply(verb, reply, args)
            if not args.wait:
                return EXIT_OK
            return _wait_arrival(args, poses, end)
        finally:
            if sub is not None:
                sub.undeclare()

    return _run(args, body)


def _wait_arrival(args: argparse.Namespace, poses: queue.Queue[bytes], end: list[float]) -> int:
    """Follow the pose until it is within 1 mm of `end` in a still state (HOLDING)."""
    deadline = time.monotonic() + args.wait_timeout
    last_rx = time.monotonic()
    last: dict[str, Any] | None = None
    while True:
        now = time.monotonic()
        if now >= deadline:
            where = "" if last is None else f"; last {format_pose(last)}"
            print(
                f"cablebot: not at the target after {args.wait_timeout:g} s{where}", file=sys.stderr
            )
            return EXIT_ABSENT
        try:
            data = poses.get(timeout=min(0.5, deadline - now))
        except queue.Empty:
            if time.monotonic() - last_rx > args.timeout:
                raise DaemonAbsent(f"no pose sample for {args.timeout:g} s") from None
            continue
        last_rx = time.monotonic()
        last = json.loads(data)
        state = str(last.get("state"))
        if state in ("FAULT", "ESTOPPED", "DISARMED"):
            raise Refused(f"the robot went {state} during the motion: {format_pose(last)}")
        pos = last.get("position_m")
        if pos is not None and state == "HOLDING" and math.dist(pos, end) <= ARRIVED_TOL_M:
            if not getattr(args, "json", False):
                print(f"arrived: {format_pose(last)}")
            return EXIT_OK


def cmd_status(args: argparse.Namespace) -> int:
    """status [--json]: print the daemon's status."""

    def body(session: Any) -> int:
        st = query(session, _key(args, "status"), None, args.timeout)
        print(json.dumps(st, indent=2) if args.json else format_status(st))
        return EXIT_OK

    return _run(args, body)


def cmd_pose(args: argparse.Namespace) -> int:
    """pose [--count N] [--json]: follow the pose until N samples (or Ctrl-C)."""

    def body(session: Any) -> int:
        poses: queue.Queue[bytes] = queue.Queue(maxsize=10_000)

        def on_sample(s: Any) -> None:
            with suppress(queue.Full):
                poses.put_nowait(s.payload.to_bytes())

        sub = session.declare_subscriber(_key(args, "pose"), on_sample)
        try:
            n = 0
            while args.count is None or n < args.count:
                try:
                    data = poses.get(timeout=args.timeout)
                except queue.Empty:
                    raise DaemonAbsent(f"no pose sample within {args.timeout:g} s") from None
                if args.json:
                    print(data.decode(), flush=True)
                else:
                    print(format_pose(json.loads(data)), flush=True)
                n += 1
        finally:
            sub.undeclare()
        return EXIT_OK

    return _run(args, body)


# --------------------------------------------------------------------------------------------
# Registration


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--connect",
        default=DEFAULT_ENDPOINT,
        metavar="ENDPOINT",
        help=f"Zenoh endpoint of the daemon (default {DEFAULT_ENDPOINT})",
    )
    p.add_argument(
        "--prefix",
        default=DEFAULT_PREFIX,
        help=f"key prefix of the robot (default {DEFAULT_PREFIX})",
    )
    p.add_argument(
        "--zenoh-config",
        default=None,
        metavar="FILE",
        help="Zenoh JSON5 configuration for this client (e.g. TLS certificates)",
    )
    p.add_argument(
        "--timeout",
        type=float,
        default=5.0,
        metavar="S",
        help="seconds to wait for a reply or a sample (default 5)",
    )


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register pose, status, move, path, stop, estop, arm, disarm, reset, home."""
    p = sub.add_parser("pose", help="follow the published pose")
    _common(p)
    p.add_argument("--count", type=int, default=None, metavar="N", help="stop after N samples")
    p.add_argument("--json", action="store_true", help="print the raw JSON samples")
    p.set_defaults(func=cmd_pose)

    p = sub.add_parser("status", help="print the daemon's status")
    _common(p)
    p.add_argument("--json", action="store_true", help="print the raw JSON status")
    p.set_defaults(func=cmd_status)

    for verb, what in (("move", "move in a straight line to X Y Z"), ("path", "follow a path")):
        p = sub.add_parser(verb, help=what)
        _common(p)
        if verb == "move":
            add_xyz_arguments(p)
        else:
            p.add_argument("file", metavar="FILE", help="JSON points or CSV x,y,z lines")
        p.add_argument(
            "--speed",
            type=float,
            default=None,
            metavar="V",
            help=(
                f"speed in m/s, at least {MIN_SPEED_MPS:g}; above the robot's maximum it runs at"
                " the maximum"
            ),
        )
        p.add_argument("--wait", action="store_true", help="wait until the end point is reached")
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
        _common(p)
        p.add_argument("--json", action="store_true", help="print the raw JSON reply")
        p.set_defaults(func=cmd_simple)

    p = sub.add_parser("home", help="declare that the effector is now at X Y Z")
    _common(p)
    add_xyz_arguments(p)
    p.add_argument("--json", action="store_true", help="print the raw JSON reply")
    p.set_defaults(func=cmd_home)
