"""`cablebot jog`: fly the robot from the keyboard, by velocity input on `<prefix>/velocity`.

Keys (the terminal in raw mode): arrows or W A S D move in x/y (right/D +x, left/A -x, up/W
+y, down/S -y), R / F or PgUp / PgDn move in z (up / down), `+` / `-` change the speed along
`SPEEDS_MPS` (capped to the robot's `max_speed_mps`), space stops (a zero sample: brake to a
hold), `q` (or Ctrl-C, Ctrl-D) sends a zero sample and quits. One line shows the robot's
state and pose (from `<prefix>/pose`), the speed and the velocity sent.

A terminal reports a held key as the key repeated (after its repeat delay, often 250-600 ms,
then 25-40 times a second); no key-up events exist. So a key counts as held until no repeat
of it came for `--release` s (0.15 s); the first press is held for at least `--first-hold` s
(0.5 s), to bridge the repeat delay (a tap is a nudge that long). While a key is held, the
velocity goes out at `--rate` Hz (20), and at once when it changes; on release one zero sample
goes out. Nothing else is needed for safety: the daemon brakes to a hold by itself when no
sample arrives for `[limits] velocity_timeout_s` (the dead-man), so a killed jog, a closed
laptop or a lost network stops the robot too.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import select
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

from controller.cli import exitcodes

Vec3 = tuple[float, float, float]

SPEEDS_MPS: tuple[float, ...] = (0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
"""The speeds `+` and `-` step through (m/s), capped to the robot's maximum."""
DEFAULT_SPEED_MPS = 0.1
RELEASE_S = 0.15
FIRST_HOLD_S = 0.5
PUBLISH_HZ = 20.0
DRAW_HZ = 10.0
POLL_S = 0.02
POSE_STALE_S = 1.0

_AXES = {"x": 0, "y": 1, "z": 2}
_TOKENS: dict[bytes, str] = {
    # escape sequences (normal and application cursor mode)
    b"\x1b[A": "y+",
    b"\x1b[B": "y-",
    b"\x1b[C": "x+",
    b"\x1b[D": "x-",
    b"\x1bOA": "y+",
    b"\x1bOB": "y-",
    b"\x1bOC": "x+",
    b"\x1bOD": "x-",
    b"\x1b[5~": "z+",
    b"\x1b[6~": "z-",
    # single bytes
    b"w": "y+",
    b"s": "y-",
    b"d": "x+",
    b"a": "x-",
    b"r": "z+",
    b"f": "z-",
    b"+": "faster",
    b"=": "faster",
    b"-": "slower",
    b"_": "slower",
    b" ": "stop",
    b"q": "quit",
    b"\x03": "quit",  # Ctrl-C (raw mode: no SIGINT)
    b"\x04": "quit",  # Ctrl-D
}
_ESCAPES = sorted((k for k in _TOKENS if k.startswith(b"\x1b")), key=len, reverse=True)


def parse_keys(data: bytes) -> tuple[list[str], bytes]:
    """The key tokens in `data` (what the terminal sent) and an unfinished escape sequence at
    its end (to prepend to the next read). Unknown keys and sequences are skipped.

    Tokens: "x+", "x-", "y+", "y-", "z+", "z-", "faster", "slower", "stop", "quit".
    Raises nothing.
    """
    out: list[str] = []
    i = 0
    n = len(data)
    while i < n:
        b = data[i : i + 1]
        if b == b"\x1b":
            for seq in _ESCAPES:
                if data.startswith(seq, i):
                    out.append(_TOKENS[seq])
                    i += len(seq)
                    break
            else:
                rest = data[i:]
                if any(seq.startswith(rest) for seq in _ESCAPES):
                    return out, rest  # cut in the middle of a sequence: wait for the rest
                # An unknown sequence (a function key): skip ESC and its CSI parameters.
                j = i + 1
                if j < n and data[j : j + 1] in (b"[", b"O"):
                    j += 1
                    while j < n and not (0x40 <= data[j] <= 0x7E):
                        j += 1
                    j += 1
                i = j
            continue
        token = _TOKENS.get(b.lower())
        if token is not None:
            out.append(token)
        i += 1
    return out, b""


@dataclass
class _Held:
    sign: float
    last_s: float
    repeats: int = 0


@dataclass
class Jog:
    """The keyboard's state: which directions are held, the speed, the velocity to send.

    Pure (no I/O): `key(token, now_s)` takes a key token from `parse_keys`, `velocity(now_s)`
    is the velocity to send now (zero once every key is released). Raises nothing.
    """

    speed_mps: float = DEFAULT_SPEED_MPS
    max_speed_mps: float | None = None
    release_s: float = RELEASE_S
    first_hold_s: float = FIRST_HOLD_S
    held: dict[int, _Held] = field(default_factory=dict)

    def speeds(self) -> tuple[float, ...]:
        """The speeds `+`/`-` step through, capped to the robot's maximum."""
        cap = self.max_speed_mps
        if cap is None:
            return SPEEDS_MPS
        return (*(s for s in SPEEDS_MPS if s < cap), cap)

    def key(self, token: str, now_s: float) -> str | None:
        """Apply one key token; returns "stop" or "quit" when the caller must act, else None."""
        if token in ("stop", "quit"):
            self.held.clear()
            return token
        if token == "faster":
            up = [s for s in self.speeds() if s > self.speed_mps * (1 + 1e-9)]
            if up:
                self.speed_mps = up[0]
            return None
        if token == "slower":
            down = [s for s in self.speeds() if s < self.speed_mps * (1 - 1e-9)]
            if down:
                self.speed_mps = down[-1]
            return None
        axis = _AXES[token[0]]
        sign = 1.0 if token[1] == "+" else -1.0
        h = self.held.get(axis)
        if h is not None and h.sign == sign:
            h.last_s = now_s
            h.repeats += 1
        else:
            self.held[axis] = _Held(sign, now_s)
        return None

    def velocity(self, now_s: float) -> Vec3:
        """The velocity to send at `now_s` (m/s): the held directions at the current speed
        (a diagonal is as fast as a straight line); released keys are dropped."""
        d = [0.0, 0.0, 0.0]
        for axis, h in list(self.held.items()):
            window = self.release_s if h.repeats > 0 else max(self.release_s, self.first_hold_s)
            if now_s - h.last_s > window:
                del self.held[axis]
            else:
                d[axis] = h.sign
        n = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if n == 0.0:
            return (0.0, 0.0, 0.0)
        k = self.speed_mps / n
        return (d[0] * k, d[1] * k, d[2] * k)


def status_line(
    pose: dict[str, Any] | None, pose_age_s: float | None, jog: Jog, sent: Vec3, width: int
) -> str:
    """The one status line: state, pose, speed, the velocity sent (cut to `width`)."""
    if pose is None or pose_age_s is None or pose_age_s > POSE_STALE_S:
        state = "?"
        where = "no pose" if pose is None else f"no pose for {pose_age_s or 0.0:.1f} s"
    else:
        state = str(pose.get("state") or "?")
        p = pose.get("position_m")
        if isinstance(p, list) and len(p) == 3:
            where = f"x {p[0]:+8.3f}  y {p[1]:+8.3f}  z {p[2]:+7.3f} m"
        else:
            where = "pose not valid"
    line = (
        f"{state:<9} {where}  speed {jog.speed_mps:g} m/s"
        f"  v [{sent[0]:+.2f} {sent[1]:+.2f} {sent[2]:+.2f}]"
    )
    if state in ("DISARMED", "FAULT", "ESTOPPED", "ARMING"):
        line += "  (not armed: samples are discarded)"
    return line[: max(10, width - 1)]


KEYS_HELP = (
    "cablebot jog: arrows/WASD x-y  R/F or PgUp/PgDn z  +/- speed  space stop  q quit"
    "  (release a key: brake to a hold)"
)


@contextlib.contextmanager
def _raw(fd: int) -> Iterator[None]:
    """The terminal on `fd` in raw mode while inside; restored after, whatever happens."""
    import termios
    import tty

    saved = termios.tcgetattr(fd)
    try:
        tty.setraw(fd)
        yield
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)


def cmd_jog(args: argparse.Namespace) -> int:
    """`cablebot jog`: fly the robot from the keyboard until `q`."""
    from controller.cli.session import run_with_session
    from controller.core.motion import check_speed

    for name in ("rate", "release", "first_hold"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0.0):
            print(f"cablebot: --{name.replace('_', '-')} must be > 0, got {v}", file=sys.stderr)
            return exitcodes.USAGE
    why = check_speed(args.speed)
    if why is not None:
        print(f"cablebot: --speed {why}", file=sys.stderr)
        return exitcodes.USAGE
    fd: int | None = None
    with contextlib.suppress(AttributeError, ValueError, OSError):
        if sys.stdin.isatty():
            fd = sys.stdin.fileno()
    if fd is None:
        print("cablebot: jog reads keys from a terminal: run it in one", file=sys.stderr)
        return exitcodes.USAGE

    def body(session: Any) -> int:
        from controller.cli.client import robot_of

        robot = robot_of(args, session)
        status = robot.status()  # the daemon is there
        jog = Jog(
            speed_mps=float(args.speed),
            max_speed_mps=status.max_speed_mps,
            release_s=float(args.release),
            first_hold_s=float(args.first_hold),
        )
        if jog.max_speed_mps is not None:
            jog.speed_mps = min(jog.speed_mps, jog.max_speed_mps)
        robot.latest_pose()  # subscribe now: the line shows the pose from the first draw
        zero: Vec3 = (0.0, 0.0, 0.0)

        def send(v: Vec3) -> None:
            robot.velocity(v)

        out = sys.stdout
        out.write(KEYS_HELP + "\r\n")
        out.flush()
        period_s = 1.0 / args.rate
        sent: Vec3 = zero
        next_pub_s = 0.0
        next_draw_s = 0.0
        pending = b""
        try:
            with _raw(fd):
                while True:
                    # Short waits: a release (0.15 s) and the next sample (50 ms) are noticed
                    # within 20 ms; an idle jog costs a few wake-ups a second.
                    ready, _, _ = select.select([fd], [], [], POLL_S)
                    now = time.monotonic()
                    if ready:
                        data = os.read(fd, 64)
                        if not data:
                            send(zero)
                            return exitcodes.OK
                        tokens, pending = parse_keys(pending + data)
                        for token in tokens:
                            action = jog.key(token, now)
                            if action == "quit":
                                send(zero)
                                return exitcodes.OK
                            if action == "stop":
                                send(zero)
                                sent = zero
                    elif pending:
                        pending = b""  # a lone ESC: no sequence follows
                    v = jog.velocity(now)
                    if v != zero:
                        if v != sent or now >= next_pub_s:
                            send(v)
                            sent = v
                            next_pub_s = now + period_s
                    elif sent != zero:
                        send(zero)  # released: brake to a hold
                        sent = zero
                    if now >= next_draw_s:
                        pose = robot.latest_pose()
                        sample = None if pose is None else pose.as_dict()
                        age = None if pose is None else now - pose.received_s
                        width = _width()
                        out.write("\r" + status_line(sample, age, jog, sent, width) + "\x1b[K")
                        out.flush()
                        next_draw_s = now + 1.0 / DRAW_HZ
        finally:
            with contextlib.suppress(Exception):
                send(zero)
            out.write("\r\n")
            out.flush()
            robot.close()

    return run_with_session(args, body)


def _width() -> int:
    try:
        return os.get_terminal_size(sys.stdout.fileno()).columns
    except (OSError, ValueError, AttributeError):
        return 100


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `jog`."""
    from controller.cli.session import add_connection_arguments

    p = sub.add_parser(
        "jog",
        help="fly the robot from the keyboard (velocity input): arrows/WASD, R/F, +/-, space, q",
    )
    add_connection_arguments(p)
    p.add_argument(
        "--speed",
        type=float,
        default=DEFAULT_SPEED_MPS,
        metavar="MPS",
        help=f"starting speed in m/s (default {DEFAULT_SPEED_MPS}); +/- step it",
    )
    p.add_argument(
        "--rate",
        type=float,
        default=PUBLISH_HZ,
        metavar="HZ",
        help=f"velocity samples a second while a key is held (default {PUBLISH_HZ:g})",
    )
    p.add_argument(
        "--release",
        type=float,
        default=RELEASE_S,
        metavar="S",
        help=f"a key counts as released after no repeat for this long (default {RELEASE_S})",
    )
    p.add_argument(
        "--first-hold",
        type=float,
        default=FIRST_HOLD_S,
        metavar="S",
        help="the first press counts as held at least this long, bridging the terminal's"
        f" key-repeat delay (default {FIRST_HOLD_S})",
    )
    p.set_defaults(func=cmd_jog)
