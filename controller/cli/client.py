"""Client CLI verbs that talk to a running daemon over Zenoh.

`cablebot pose|status|move|path|stop|estop|arm|disarm|reset|home`, connecting to
`tcp/127.0.0.1:7447` by default (`--connect ENDPOINT` or `HOST:PORT`, `--prefix PREFIX`).

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
import re
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager, suppress
from typing import Any, TextIO

from controller.cli import add_xyz_arguments, exitcodes, xyz_from_args
from controller.core.motion import MIN_SPEED_MPS, check_speed

EXIT_OK = exitcodes.OK
EXIT_REFUSED = exitcodes.REFUSED
EXIT_USAGE = exitcodes.USAGE
EXIT_ABSENT = exitcodes.NO_DAEMON
EXIT_WAIT_TIMEOUT = exitcodes.WAIT_TIMEOUT

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_PREFIX = "cablebot/default"
ARRIVED_TOL_M = 1e-3
DEFAULT_POSE_RATE_HZ = 5.0
PROGRESS_PERIOD_S = 0.1

# Zenoh link protocols a client may name in an endpoint; those with HOST:PORT addresses are
# checked here so that a typo gets a one-line answer instead of a connection attempt.
_PORT_PROTOCOLS = frozenset({"tcp", "udp", "tls", "quic", "ws"})
_OTHER_PROTOCOLS = frozenset({"unixsock-stream", "unixpipe", "serial", "vsock"})
_HOST_PORT = re.compile(r"(\[[0-9A-Fa-f:.%a-zA-Z]+\]|[A-Za-z0-9_.-]+):([0-9]{1,5})")
_RUST_LOCATION = re.compile(r" at /\S+\.rs:\d+\.?")


class DaemonAbsent(RuntimeError):
    """No daemon answered: nothing listening on the endpoint, wrong prefix, or no reply in time.

    `live` names the prefixes of the daemons that are alive on the same network (filled in by
    `run_with_session`), for the error message."""

    live: tuple[str, ...] = ()


class Refused(RuntimeError):
    """The daemon answered with an error reply; the message is its reason."""


class InputError(ValueError):
    """The user's input (numbers, path file) is invalid; nothing was sent."""


class UsageError(ValueError):
    """A command-line value that cannot be used (e.g. `--connect`); nothing was sent."""


class WaitTimeout(RuntimeError):
    """`--wait`: the robot did not reach the end point in time."""


# --------------------------------------------------------------------------------------------
# Session and queries


def normalize_endpoint(text: str, option: str = "--connect") -> str:
    """The Zenoh endpoint for an endpoint option's value: `HOST:PORT` becomes `tcp/HOST:PORT`.

    The one reading of an endpoint given on the command line (`--connect` of every verb,
    `replay --listen`). Accepts `PROTO/ADDRESS` for Zenoh's link protocols (`tcp`, `udp`,
    `tls`, `quic`, `ws` need `HOST:PORT` with a port 1..65535). Raises UsageError (one line,
    naming `option`) for anything else.
    """
    t = text.strip()
    bad = UsageError(f"{option}: expected tcp/HOST:PORT or HOST:PORT, got {text!r}")
    if "/" in t:
        proto, _, address = t.partition("/")
        if proto in _OTHER_PROTOCOLS and address:
            return t
        if proto not in _PORT_PROTOCOLS:
            raise bad
        host_port = re.split(r"[?#]", address, maxsplit=1)[0]
    else:
        host_port = t
    m = _HOST_PORT.fullmatch(host_port)
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        raise bad
    return t if "/" in t else f"tcp/{t}"


def clean_zenoh_error(text: str) -> str:
    """A Zenoh error message on one line, without the Rust source locations."""
    one = " ".join(text.split())
    return _RUST_LOCATION.sub("", one)


@contextmanager
def open_session(endpoint: str, *, config_file: str | None = None) -> Iterator[Any]:
    """Open a client-mode Zenoh session connected to `endpoint` (any form `normalize_endpoint`
    takes, e.g. `HOST:PORT`); close it on exit.

    Raises UsageError for an endpoint or `--zenoh-config` file that Zenoh rejects, and
    DaemonAbsent when nothing accepts the connection.
    """
    import zenoh

    from controller.service.zenoh_io import client_config

    endpoint = normalize_endpoint(endpoint)
    try:
        conf = client_config([endpoint], config_file=config_file)
    except zenoh.ZError as exc:
        what = f"--zenoh-config {config_file}" if config_file else f"--connect {endpoint}"
        raise UsageError(f"{what}: {clean_zenoh_error(str(exc))}") from None
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        raise DaemonAbsent(f"cannot connect to {endpoint}: {clean_zenoh_error(str(exc))}") from None
    try:
        yield session
    finally:
        session.close()  # type: ignore[no-untyped-call]


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


LIVELINESS_TIMEOUT_S = 1.0
"""How long `live_prefixes` waits for the daemons' liveliness tokens."""


def live_prefixes(session: Any, timeout_s: float = LIVELINESS_TIMEOUT_S) -> list[str]:
    """The key prefixes of every daemon alive on the session's network (each daemon declares
    the liveliness token `<prefix>/alive` while its Zenoh interface is open), sorted.

    Raises nothing: a failed lookup is an empty list."""
    found: set[str] = set()
    try:
        for reply in session.liveliness().get("**/alive", timeout=timeout_s):
            if reply.ok is not None:
                key = str(reply.ok.key_expr)
                if key.endswith("/alive"):
                    found.add(key.removesuffix("/alive"))
    except Exception:  # a closing session: nothing to name
        return []
    return sorted(found)


def _absent_message(args: argparse.Namespace, exc: DaemonAbsent) -> str:
    text = f"no cablebot daemon answered on {args.prefix} via {args.connect} ({exc})"
    others = [p for p in exc.live if p != args.prefix.rstrip("/")]
    if others:
        text += (
            f"; live daemons there: {', '.join(others)} (give --prefix {others[0]};"
            " `cablebot list` shows them)"
        )
    return text


def run_with_session(args: argparse.Namespace, body: Callable[[Any], int]) -> int:
    """Run `body(session)` with the CLI's error handling; returns the exit code.

    Every failure is one line on stderr: a refusal prints the daemon's reason verbatim; when
    no daemon answers on `--prefix`, the line names the prefixes of the daemons that are alive.
    """
    try:
        endpoint = normalize_endpoint(args.connect)
        args.connect = endpoint
        with open_session(endpoint, config_file=args.zenoh_config) as session:
            try:
                code: int = body(session)
            except DaemonAbsent as exc:
                exc.live = tuple(live_prefixes(session))
                raise
            return code
    except UsageError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except DaemonAbsent as exc:
        print(f"cablebot: {_absent_message(args, exc)}", file=sys.stderr)
        return EXIT_ABSENT
    except Refused as exc:
        print(f"cablebot: refused: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except InputError as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_REFUSED
    except WaitTimeout as exc:
        print(f"cablebot: {exc}", file=sys.stderr)
        return EXIT_WAIT_TIMEOUT
    except KeyboardInterrupt:
        return exitcodes.INTERRUPTED


_run = run_with_session


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


def axis_state_text(ax: dict[str, Any]) -> str:
    """An axis's state as its drive names it (the status entry's "state", e.g.
    "CLOSED_LOOP_CONTROL" or "Operation enabled"); "state N" from the raw number when the
    entry has no name."""
    name = ax.get("state")
    if isinstance(name, str) and name:
        return name
    return f"state {ax.get('axis_state')}"


def axis_fault_text(ax: dict[str, Any]) -> str:
    """An axis's fault as its drive names it (the status entry's "fault", e.g.
    "ESTOP_REQUESTED (0x2000000)"), "none" without one; the raw error number when the entry
    has no name."""
    if "fault" in ax:
        fault = ax["fault"]
        return "none" if fault is None else str(fault)
    err = ax.get("axis_error")
    if isinstance(err, int) and not isinstance(err, bool):
        return "none" if err == 0 else f"0x{err:x}"
    return str(err)


def status_tensions_n(st: dict[str, Any]) -> list[float | None] | None:
    """The cable tensions (N, cable order) a status carries, or None when it has none."""
    for holder in (st, st.get("statics"), st.get("pose")):
        if isinstance(holder, dict) and isinstance(holder.get("tensions_n"), list):
            return [v if isinstance(v, int | float) else None for v in holder["tensions_n"]]
    return None


def format_status(st: dict[str, Any]) -> str:
    """A short multi-line summary of a status reply (axis states and faults by the drives'
    names)."""
    lines = [f"state      {st.get('state')}" + (f" ({st['reason']})" if st.get("reason") else "")]
    pose = st.get("pose") or {}
    if pose.get("position_m") is not None:
        x, y, z = pose["position_m"]
        lines.append(f"position   x={x:+.4f} y={y:+.4f} z={z:+.4f} m")
    else:
        lines.append("position   not valid")
    sp = st.get("setpoint_m")
    if isinstance(sp, list) and len(sp) == 3:
        lines.append(f"set-point  x={sp[0]:+.4f} y={sp[1]:+.4f} z={sp[2]:+.4f} m")
    if "homed" in st:
        lines.append(f"homed      {st.get('homed')} ({st.get('home_source')})")
    pt = st.get("pretension")
    if isinstance(pt, dict):
        res = pt.get("result")
        if pt.get("active"):
            fastest = pt.get("fastest_cable_mps")
            speed = "" if fastest is None else f", fastest cable {fastest * 1e3:.1f} mm/s"
            lines.append(
                f"pretension running {float(pt.get('elapsed_s') or 0.0):.1f} s{speed}, home at "
                f"{_xyz(pt.get('position_m') or [])}"
            )
        elif isinstance(res, dict):
            lines.append(
                f"pretension still after {float(res.get('still_after_s', 0.0)):.2f} s, homed"
                if res.get("ok")
                else f"pretension ended without homing: {res.get('reason')}"
            )
    tensions = status_tensions_n(st)
    for i, ax in enumerate(st.get("axes", [])):
        age = ax.get("age_s")
        age_s = "never" if age is None else f"{age * 1e3:.1f} ms ago"
        tension = ""
        if tensions is not None and i < len(tensions) and tensions[i] is not None:
            tension = f"  tension {tensions[i]:.1f} N"
        lines.append(
            f"axis {ax.get('node_id')!s:<5} {axis_state_text(ax)}, error"
            f" {axis_fault_text(ax)}, reading {age_s}{tension}"
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
            f"  commands heard {bus.get('commands_heard', 0)} (own echoes or another master)"
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


def _xyz(p: Sequence[Any], digits: int = 3) -> str:
    return " ".join(f"{a}={float(v):+.{digits}f}" for a, v in zip("xyz", p, strict=False)) + " m"


def format_reply(verb: str, reply: Any) -> str:
    """One readable line for a command's reply (what the robot does now)."""
    if not isinstance(reply, dict):
        return f"{verb}: ok"
    state = reply.get("state")
    if verb == "stop":
        if state == "MOVING":
            return "stop: braking to a hold"
        if state == "HOLDING":
            return "stop: holding (nothing was moving)"
        return f"stop: nothing to stop (state {state})"
    if verb == "home":
        return format_home(reply)
    if verb == "pretension":
        tensions = reply.get("tensions_n")
        text = "pretension: the reels pull in torque control"
        if isinstance(tensions, list) and tensions:
            text += " with " + ", ".join(f"{float(t):.1f}" for t in tensions) + " N"
        if reply.get("speed_limited") is False:
            text += " (the drives' own velocity limit caps their speed)"
        return text + "; waiting until they are still"
    known = {"ok", "state"}
    if verb in ("move", "path"):
        known |= {"target_m", "points", "speed_mps", "speed_limited_to_mps"}
        speed = reply.get("speed_mps")
        at = "" if not isinstance(speed, int | float) else f" at {speed:.3f} m/s"
        limited = reply.get("speed_limited_to_mps")
        if isinstance(limited, int | float):
            at += f" (speed limited to the robot's maximum, {limited:.3f} m/s)"
        target = reply.get("target_m")
        if verb == "move" and isinstance(target, list):
            text = f"move: to {_xyz(target)}{at}"
        elif verb == "path" and isinstance(reply.get("points"), int):
            text = f"path: {reply['points']} points{at}"
        else:
            text = f"{verb}: ok{at}"
    else:
        text = f"{verb}: ok" + (f", state {state}" if state is not None else "")
    extra = " ".join(f"{k}={v}" for k, v in reply.items() if k not in known)
    return f"{text} {extra}".rstrip()


def format_home(reply: dict[str, Any]) -> str:
    """The `home` reply: the declared position, the offsets (4 decimals of a turn), saved where."""
    parts = ["home:"]
    pos = reply.get("position_m")
    if isinstance(pos, list):
        parts.append(f"at {_xyz(pos, 4)};")
    offsets = reply.get("offsets_rev")
    if isinstance(offsets, dict) and offsets:
        parts.append(
            "offsets (turns) "
            + ", ".join(f"node {k} {float(v):+.4f}" for k, v in offsets.items())
            + ";"
        )
    if reply.get("saved"):
        parts.append(f"saved to {reply.get('state_file')}")
    elif reply.get("error"):
        parts.append(f"NOT SAVED: {reply['error']}")
    else:
        parts.append("not saved (no [homing] state_file)")
    return " ".join(parts)


def _ms(v: Any) -> str:
    return "-" if v is None else f"{float(v) * 1e3:.2f} ms"


def _us(v: Any) -> str:
    return "-" if v is None else f"{float(v):.0f} us"


# --------------------------------------------------------------------------------------------
# Following a stream: sequence gaps, rate limiting, progress


class SeqGaps:
    """Counts samples missed from a stream numbered by `seq` (one per published sample).

    `update(seq)` returns how many samples were missed just before this one (0 when in
    order). A `seq` that goes backwards means the daemon restarted: counting starts again.
    """

    def __init__(self) -> None:
        self.last: int | None = None
        self.received = 0
        self.missed = 0
        self.restarts = 0

    def update(self, seq: Any) -> int:
        """Record one received `seq`; returns the samples missed before it."""
        self.received += 1
        if not isinstance(seq, int):
            return 0
        gap = 0
        if self.last is not None:
            if seq <= self.last:
                self.restarts += 1
            else:
                gap = seq - self.last - 1
        self.last = seq
        self.missed += gap
        return gap


def path_remaining_m(
    legs: Sequence[tuple[Sequence[float], Sequence[float]]], pos: Sequence[float], leg: int
) -> tuple[int, float]:
    """Distance (m) still to travel along `legs` from `pos`, and the leg it is on now.

    `leg` is the leg the effector was on before; it only moves forward (to the nearest of this
    leg and the next two), so a path that crosses itself is followed in order. The distance is
    from `pos` to the end of its leg plus the lengths of the legs after it.
    """
    best, best_d = leg, math.inf
    for k in range(leg, min(leg + 3, len(legs))):
        d = _point_segment_m(pos, legs[k][0], legs[k][1])
        if d < best_d - 1e-9:
            best, best_d = k, d
    rest = sum(math.dist(a, b) for a, b in legs[best + 1 :])
    return best, math.dist(pos, legs[best][1]) + rest


def _point_segment_m(p: Sequence[float], a: Sequence[float], b: Sequence[float]) -> float:
    ab = [b[i] - a[i] for i in range(3)]
    ap = [p[i] - a[i] for i in range(3)]
    den = sum(v * v for v in ab)
    t = 0.0 if den <= 0.0 else max(0.0, min(1.0, sum(ab[i] * ap[i] for i in range(3)) / den))
    return math.dist(p, [a[i] + t * ab[i] for i in range(3)])


class StatusLine:
    """One line of progress rewritten in place on a terminal; does nothing elsewhere."""

    def __init__(self, stream: TextIO, *, enabled: bool) -> None:
        self.stream = stream
        self.enabled = enabled
        self._shown = False
        self._next_s = 0.0

    def show(self, text: str, now_s: float) -> None:
        """Replace the line with `text` (at most every PROGRESS_PERIOD_S)."""
        if not self.enabled or now_s < self._next_s:
            return
        self._next_s = now_s + PROGRESS_PERIOD_S
        self.stream.write("\r\x1b[K" + text)
        self.stream.flush()
        self._shown = True

    def clear(self) -> None:
        """Erase the line (before printing a normal line)."""
        if self._shown:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self._shown = False


def _isatty(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


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

    Returns the `path` command payload. Raises InputError for an unreadable, not UTF-8 or
    invalid file.
    """
    from controller.service.textfile import NotUtf8Error, read_text

    try:
        text = read_text(path)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from None
    except NotUtf8Error as exc:
        raise InputError(f"{path}: {exc}") from None
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
    from controller.core.commands import MAX_PATH_POINTS_SENT, CommandError, parse_command

    pts = payload.get("points_m")
    if isinstance(pts, list) and len(pts) > MAX_PATH_POINTS_SENT:
        raise InputError(
            f"{path}: {len(pts)} points; one path command takes at most {MAX_PATH_POINTS_SENT}"
            f" points: split it into parts of at most {MAX_PATH_POINTS_SENT} points and send"
            " each with its own path command"
        )

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
        return EXIT_OK

    return _run(args, body)


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
    declared (HOLDING), or the reason it did not. Raises Refused, WaitTimeout, DaemonAbsent."""

    def body(session: Any) -> int:
        reply = query(session, _key(args, "cmd/pretension"), payload, args.timeout)
        _print_reply("pretension", reply, args)
        line = StatusLine(sys.stdout, enabled=_isatty(sys.stdout) and not args.json)
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
                    raise Refused(f"the pre-tension ended in {state}: {st.get('reason')}")
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


def format_pretension_result(result: dict[str, Any]) -> str:
    """The end of a pre-tension: how long until still, where homed, the tensions."""
    parts = [
        f"pretension: still after {float(result.get('still_after_s', 0.0)):.2f} s",
        "homed " + format_home(result).removeprefix("home: "),
    ]
    measured = result.get("measured_tensions_n")
    if isinstance(measured, list) and measured and None not in measured:
        parts.append("measured tensions " + ", ".join(f"{t:.1f}" for t in measured) + " N")
    return "; ".join(parts)


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
    return _motion(args, "move", payload, [target])


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
    points = [[float(v) for v in p] for p in payload["points_m"]]
    return _motion(args, "path", payload, points)


def _motion(
    args: argparse.Namespace, verb: str, payload: dict[str, Any], points: list[list[float]]
) -> int:
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
            # The daemon replies once the motion has started (MOVING). Poses published before it
            # took the command may already be in the queue, HOLDING where a path also ends: they
            # must not count as arrival. Unless the motion is already over, wait to see it move.
            status = query(session, _key(args, "status"), None, args.timeout)
            moving = isinstance(status, dict) and status.get("state") == "MOVING"
            return _wait_arrival(args, verb, poses, points, seen_moving=not moving)
        except KeyboardInterrupt:
            return _interrupted(session, args)
        finally:
            if sub is not None:
                sub.undeclare()

    return _run(args, body)


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
    poses: queue.Queue[bytes],
    points: list[list[float]],
    *,
    seen_moving: bool = True,
) -> int:
    """Follow the pose until it is within 1 mm of the last point in a still state (HOLDING).

    With `seen_moving` False, HOLDING samples count only after a MOVING one (the motion was
    still running when the wait began, and older samples may stand where the path ends).

    On a terminal (and without `--json`) one line shows the distance still to travel, rewritten
    in place. At the end it prints "arrived: <pose>" (with `--json` a line
    `{"arrived": true, "pose": <the pose sample>}`). Raises WaitTimeout, Refused (the robot
    left the motion states) or DaemonAbsent.
    """
    end = points[-1]
    line = StatusLine(sys.stdout, enabled=_isatty(sys.stdout) and not args.json)
    t0 = time.monotonic()
    deadline = t0 + args.wait_timeout
    last_rx = t0
    last: dict[str, Any] | None = None
    legs: list[tuple[list[float], list[float]]] | None = None
    leg = 0
    try:
        while True:
            now = time.monotonic()
            if now >= deadline:
                where = "" if last is None else f"; last {format_pose(last)}"
                raise WaitTimeout(f"not at the target after {args.wait_timeout:g} s{where}")
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
            if pos is None:
                continue
            if state == "MOVING":
                seen_moving = True
            if state == "HOLDING" and seen_moving and math.dist(pos, end) <= ARRIVED_TOL_M:
                line.clear()
                if args.json:
                    print(json.dumps({"arrived": True, "pose": last}), flush=True)
                else:
                    print(f"arrived: {format_pose(last)}", flush=True)
                return EXIT_OK
            if legs is None:
                starts = [list(pos), *points[:-1]]
                legs = list(zip(starts, points, strict=True))
            leg, remaining = path_remaining_m(legs, pos, leg)
            line.show(
                f"{verb}: {remaining:.3f} m to go  {state}  {_xyz(pos)}  {last_rx - t0:.1f} s",
                last_rx,
            )
    finally:
        line.clear()


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


def format_daemons(rows: Sequence[dict[str, Any]]) -> str:
    """The `list` table: one line per daemon (prefix, name, state, endpoints)."""
    table = [("PREFIX", "NAME", "STATE", "ENDPOINT")]
    for r in rows:
        listen = r.get("listen")
        table.append(
            (
                str(r["prefix"]),
                "-" if r.get("name") is None else str(r["name"]),
                "-" if r.get("state") is None else str(r["state"]),
                "-" if not listen else ", ".join(str(e) for e in listen),
            )
        )
    widths = [max(len(row[i]) for row in table) for i in range(3)]
    return "\n".join(
        "  ".join(cell.ljust(w) for cell, w in zip(row[:3], widths, strict=True)) + "  " + row[3]
        for row in table
    )


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


def add_connection_arguments(p: argparse.ArgumentParser) -> None:
    """Add `--connect`, `--prefix`, `--zenoh-config` and `--timeout` to a verb's parser."""
    p.add_argument(
        "--connect",
        default=DEFAULT_ENDPOINT,
        metavar="ENDPOINT",
        help=f"the daemon's endpoint, PROTO/HOST:PORT or HOST:PORT (default {DEFAULT_ENDPOINT})",
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
    add_connection_arguments(p)
    p.add_argument("--count", type=int, default=None, metavar="N", help="stop after N lines")
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
