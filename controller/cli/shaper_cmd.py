"""`cablebot shaper TYPE [--frequency-hz F] [--damping-ratio Z]`: change a running robot's
input shaper (the daemon's `shaper` command: at once when the set-point is at rest, else when
the motion ends). TYPE is one of `controller.core.motion.shaper.SHAPER_TYPES` ("off" for
none); without `--frequency-hz` the model's modes at the set-point, without
`--damping-ratio` the robot's current one. An unknown type gets a did-you-mean before anything
is sent; the daemon refuses a frequency or damping ratio out of range, or the model's modes
where it has no model, with the reason."""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from controller.cli import exitcodes


def shaper_name(kind: str, passes: int) -> str:
    """A shaper's train as the user reads it: its type, and how many times it is applied when
    more than once ("2hump_ei x2"). Raises nothing."""
    return kind if passes == 1 else f"{kind} x{passes}"


def describe(shaper: dict[str, Any]) -> str:
    """One line for a status's or reply's `shaper` object."""
    kind = shaper.get("type")
    if kind == "off":
        text = "off"
    else:
        freq = shaper.get("frequency_hz")
        where = f"at {freq:g} Hz" if freq is not None else "on the model's modes at the set-point"
        now = shaper.get("frequencies_hz") or []
        name = shaper_name(str(kind), int(shaper.get("passes") or 1))
        text = f"{name} {where}, damping ratio {shaper.get('damping_ratio'):g}"
        if now:
            text += (
                f"; now {', '.join(f'{f:.3g}' for f in now)} Hz, delay {shaper['delay_s']:.3f} s"
            )
    pending = shaper.get("pending")
    if pending is not None:
        text += f" ({pending} when the motion ends)"
    return text


def cmd_shaper(args: argparse.Namespace) -> int:
    """`cablebot shaper`: send the `shaper` command, print what the robot shapes with."""
    from controller.cli.session import query, run_with_session
    from controller.core.motion.shaper import SHAPER_TYPES
    from controller.core.suggest import closest

    kind = str(args.type)
    if kind not in SHAPER_TYPES:
        near = closest(kind.lower(), SHAPER_TYPES)
        hint = f" (did you mean {near!r}?)" if near else ""
        print(
            f"cablebot: unknown shaper type {kind!r}{hint}; one of {', '.join(SHAPER_TYPES)}",
            file=sys.stderr,
        )
        return exitcodes.REFUSED
    payload = {"type": kind, "frequency_hz": args.frequency_hz, "damping_ratio": args.damping_ratio}

    def body(session: Any) -> int:
        reply = query(session, f"{args.prefix}/cmd/shaper", payload, args.timeout)
        if args.json:
            print(json.dumps(reply, allow_nan=False))
            return exitcodes.OK
        shaper = reply.get("shaper") if isinstance(reply, dict) else None
        when = reply.get("applies") if isinstance(reply, dict) else None
        text = describe(shaper) if isinstance(shaper, dict) else "ok"
        print(f"shaper: {text}" + (" (from the end of the motion)" if when == "at rest" else ""))
        return exitcodes.OK

    return run_with_session(args, body)


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `shaper`."""
    from controller.cli.session import add_connection_arguments

    def number(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text}")
        return value

    p = sub.add_parser(
        "shaper", help="change a running robot's input shaper (type, frequency, damping ratio)"
    )
    p.add_argument("type", metavar="TYPE", help="off, zv, mzv, zvd, ei, 2hump_ei or 3hump_ei")
    p.add_argument(
        "--frequency-hz",
        type=number,
        default=None,
        metavar="F",
        help="shape one mode of this frequency (default: the model's modes at the set-point)",
    )
    p.add_argument(
        "--damping-ratio",
        type=number,
        default=None,
        metavar="Z",
        help="the modes' damping ratio, 0..0.3 (default: keep the robot's)",
    )
    p.add_argument("--json", action="store_true", help="print the daemon's reply as JSON")
    add_connection_arguments(p)
    p.set_defaults(func=cmd_shaper)
