"""`cablebot resonance X Y Z`: measure the effector's modes at a pose with the sensors the robot
already has, its motors' torque telemetry, and print a `[shaper]` to paste.

The procedure (`measure`, on any `Link`: the daemon over Zenoh, or a controller in tests):

1. Refused unless the robot is HOLDING and its torque telemetry is on (`[loop]
   torque_telemetry`: every cable's tension, the sensor).
2. Move to X Y Z (the daemon refuses a pose outside the workspace or the tension limits, with
   its reason) and wait there.
3. Shaping off (it would cancel the ringing to measure), a short rest-to-rest move of `--step`
   metres (default 2 cm) along a diagonal, so that every mode is struck; record the poses'
   measured tensions for `--seconds` after the move ends; shaping back as it was; move back.
4. Fit the free ringing (`controller.core.resonance.fit_modes`) of the force the cables put on
   the effector, starting from the model's modes at the pose (every reel's `cable_ea_n` and the
   planned tensions, from the daemon's status) where there is one; compare.

Prints each mode (frequency, damping ratio, direction, the model's frequency) and a `[shaper]`
table: the lightest damping ratio measured, and `frequency_scale` (measured over modelled
frequencies, their geometric mean) or, without a model, `frequency_hz` of the lowest mode.
`--json`: `frequencies_hz`, `damping_ratios`, `directions`, `model_frequencies_hz` (null
without a model), `frequency_scale`, `shaper`.
"""

from __future__ import annotations

import argparse
import json
import math
import queue
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from controller.cli import add_xyz_arguments, exitcodes, xyz_from_args

DEFAULT_STEP_M = 0.02
"""The excitation: a rest-to-rest move this long."""
RECORD_PERIODS = 20
"""Without `--seconds`, the record lasts this many periods of the model's lowest mode."""
RECORD_S = (3.0, 30.0)
"""... and at least and at most this long (15 s without a model)."""
POLL_S = 0.05
SAMPLES_PER_PERIOD = 2.5
"""The pose samples must come at least this many times per period of the model's highest
mode (the Nyquist rate and a margin)."""


class Link(Protocol):
    """What the measurement needs of the robot."""

    def status(self) -> dict[str, Any]:
        """The daemon's status."""

    def command(self, verb: str, payload: dict[str, Any] | None) -> dict[str, Any]:
        """Send a command; raises `controller.cli.session.Refused` with the daemon's reason."""

    def take_samples(self) -> list[dict[str, Any]]:
        """The pose samples (decoded JSON) received since the last call."""

    def pause(self, seconds: float) -> None:
        """Let `seconds` pass."""


def _wait_holding(link: Link, timeout_s: float, what: str) -> dict[str, Any]:
    """Poll until HOLDING; the status then. Raises Refused when the robot leaves the motion
    states, WaitTimeout after `timeout_s` of polls."""
    from controller.cli.session import Refused, WaitTimeout

    waited = 0.0
    while True:
        st = link.status()
        state = st.get("state")
        if state == "HOLDING":
            return st
        if state != "MOVING":
            why = f" ({st['reason']})" if st.get("reason") else ""
            raise Refused(f"the robot went {state}{why} {what}")
        if waited > timeout_s:
            raise WaitTimeout(f"still moving {timeout_s:g} s after {what}")
        link.pause(POLL_S)
        waited += POLL_S


def model_modes(status: dict[str, Any], position_m: Sequence[float]) -> Any:
    """The model's modes at `position_m` (`controller.core.vibration.Modes`) from the daemon's
    status (its configuration and the tensions it plans there), or None without a model."""
    from controller.core.vibration import ModesError, effector_modes

    cfg = status.get("config") or {}
    reels = cfg.get("reels") or []
    payload = cfg.get("payload") or {}
    planned = (status.get("tensions") or {}).get("planned_n")
    ea = [r.get("cable_ea_n") for r in reels]
    if not reels or None in ea or not payload or planned is None:
        return None
    try:
        return effector_modes(
            [r["anchor_m"] for r in reels],
            position_m,
            planned,
            ea,
            float(payload["mass_kg"]),
            cable_damping_ratio=float((cfg.get("shaper") or {}).get("damping_ratio", 0.0)),
        )
    except (ModesError, KeyError, TypeError, ValueError):
        return None


def record_seconds(model: Any, seconds: float | None) -> float:
    """How long to record the ringing: `seconds`, or `RECORD_PERIODS` periods of the model's
    lowest mode within `RECORD_S` (15 s without a model)."""
    if seconds is not None:
        return seconds
    if model is None:
        return 15.0
    return min(RECORD_S[1], max(RECORD_S[0], RECORD_PERIODS / float(model.frequencies_hz[0])))


def _excite(link: Link, target: list[float], step_m: float) -> list[float]:
    """The excitation move's end: `step_m` from `target` along the first diagonal the daemon
    accepts; sends the move. Raises Refused when it accepts none."""
    from controller.cli.session import Refused

    k = step_m / math.sqrt(3.0)
    last: Refused | None = None
    for sx, sy, sz in ((1, 1, 1), (-1, -1, -1), (1, -1, 1), (-1, 1, -1), (1, 1, -1), (-1, -1, 1)):
        end = [target[0] + sx * k, target[1] + sy * k, target[2] + sz * k]
        try:
            link.command("move", {"position_m": end})
        except Refused as exc:
            last = exc
            continue
        return end
    raise Refused(f"no {step_m:g} m excitation move fits there: {last}")


def measure(
    link: Link,
    target: list[float],
    *,
    step_m: float = DEFAULT_STEP_M,
    seconds: float | None = None,
    timeout_s: float = 120.0,
    log: Callable[[str], None] = lambda _: None,
) -> dict[str, Any]:
    """Measure the modes at `target` (module docstring); the report. Raises Refused (not
    HOLDING, no torque telemetry, a move refused), WaitTimeout, ResonanceError (no ringing to
    fit)."""
    import numpy as np

    from controller.cli.session import Refused
    from controller.core.resonance import cable_force, fit_modes

    st = link.status()
    if st.get("state") != "HOLDING":
        raise Refused(
            f"resonance needs the robot HOLDING still, it is {st.get('state')}"
            + (f" ({st['reason']})" if st.get("reason") else "")
        )
    cfg = st.get("config") or {}
    if (cfg.get("loop") or {}).get("torque_telemetry", "off") == "off":
        raise Refused(
            "resonance reads the cables' tensions from the drives' torque telemetry: set [loop] "
            'torque_telemetry = "cyclic" (or "rtr") and restart the daemon'
        )
    anchors = [r["anchor_m"] for r in cfg.get("reels", [])]
    log(f"moving to {_xyz(target)}")
    link.command("move", {"position_m": target})
    st = _wait_holding(link, timeout_s, "on the way to the pose")
    model = model_modes(st, target)
    loop = cfg.get("loop") or {}
    pose_hz = float(loop.get("rate_hz", 0.0)) / max(1, int(loop.get("publish_every", 1)))
    if model is not None and pose_hz < SAMPLES_PER_PERIOD * model.frequencies_hz[-1]:
        raise Refused(
            f"the poses (and their tensions) come at {pose_hz:g} Hz, too seldom for modes up to "
            f"{model.frequencies_hz[-1]:.3g} Hz: set [loop] publish_every so that rate_hz / "
            f"publish_every is at least {SAMPLES_PER_PERIOD * model.frequencies_hz[-1]:.0f} Hz"
        )
    record = record_seconds(model, seconds)
    before = st.get("shaper") or {}
    restore = {
        "type": before.get("type", "off"),
        "frequency_hz": before.get("frequency_hz"),
        "damping_ratio": before.get("damping_ratio"),
    }
    link.command("shaper", {"type": "off"})
    try:
        link.take_samples()
        end = _excite(link, target, step_m)
        log(f"excited: {step_m:g} m to {_xyz(end)}; recording {record:.1f} s of ringing")
        _wait_holding(link, timeout_s, "during the excitation")
        link.pause(record)
        samples = link.take_samples()
    finally:
        if restore["type"] != "off":
            link.command("shaper", restore)
    link.command("move", {"position_m": target})
    _wait_holding(link, timeout_s, "on the way back")
    times, tensions = ringing(samples)
    force = cable_force(anchors, end, np.array(tensions))
    guesses = (
        None if model is None else list(zip(model.frequencies_hz, model.directions, strict=True))
    )
    fitted = fit_modes(times, force, guesses)
    return report(
        target, end, fitted, model, len(times), times[-1] - times[0] if times else 0.0, cfg
    )


def ringing(samples: Sequence[dict[str, Any]]) -> tuple[list[float], list[list[float]]]:
    """(times in s, tensions) of the pose samples after the excitation's motion ended (the
    first HOLDING after MOVING), each a new torque reading (a tension changed), with every
    cable's measured tension."""
    times: list[float] = []
    out: list[list[float]] = []
    moved = ended = False
    last: list[float] | None = None
    for s in samples:
        state = s.get("state")
        if state == "MOVING":
            moved = True
        elif state == "HOLDING" and moved:
            ended = True
        if not ended:
            continue
        tens = s.get("measured_tensions_n")
        if not tens or any(v is None for v in tens):
            continue
        vals = [float(v) for v in tens]
        if vals == last:
            continue
        t = float(s.get("stamp_ns", 0)) * 1e-9
        if times and t <= times[-1]:
            continue
        last = vals
        times.append(t)
        out.append(vals)
    return times, out


def report(
    target: Sequence[float],
    end: Sequence[float],
    fitted: Sequence[Any],
    model: Any,
    samples: int,
    span_s: float,
    cfg: dict[str, Any],
) -> dict[str, Any]:
    """The JSON report: the measured modes, the model's, and the `[shaper]` to paste."""
    seen = [m for m in fitted if m.seen]
    if not seen:
        from controller.core.resonance import ResonanceError

        raise ResonanceError("no mode rang clearly enough to fit (a larger --step?)")
    freqs = [m.frequency_hz if m.seen else None for m in fitted]
    ratios = [m.damping_ratio if m.seen else None for m in fitted]
    model_f = None if model is None else list(model.frequencies_hz)
    scale = None
    if model_f is not None and len(model_f) == len(fitted):
        logs = [
            math.log(m.frequency_hz / g) for m, g in zip(fitted, model_f, strict=True) if m.seen
        ]
        scale = math.exp(sum(logs) / len(logs))
    sc = cfg.get("shaper") or {}
    from controller.core.motion.shaper import DEFAULT_SHAPER_TYPE

    kind = sc.get("type") if sc.get("type") not in (None, "off") else DEFAULT_SHAPER_TYPE
    shaper: dict[str, Any] = {
        "type": kind,
        "damping_ratio": round(min(m.damping_ratio for m in seen), 4),
    }
    if scale is not None:
        shaper["frequency_scale"] = round(scale, 4)
    else:
        shaper["frequency_hz"] = round(seen[0].frequency_hz, 3)
    return {
        "position_m": list(target),
        "excitation_to_m": list(end),
        "samples": samples,
        "record_s": span_s,
        "frequencies_hz": freqs,
        "damping_ratios": ratios,
        "directions": [list(m.direction) for m in fitted],
        "model_frequencies_hz": model_f,
        "model_damping_ratios": None if model is None else list(model.damping_ratios),
        "frequency_scale": scale,
        "shaper": shaper,
    }


def _xyz(p: Sequence[float]) -> str:
    return f"x={p[0]:+.3f} y={p[1]:+.3f} z={p[2]:+.3f} m"


def format_report(rep: dict[str, Any]) -> str:
    """What `cablebot resonance` prints."""
    lines = [
        f"resonance at {_xyz(rep['position_m'])}: {rep['samples']} tension samples over "
        f"{rep['record_s']:.1f} s of ringing"
    ]
    model = rep["model_frequencies_hz"]
    for j, (f, z, d) in enumerate(
        zip(rep["frequencies_hz"], rep["damping_ratios"], rep["directions"], strict=True)
    ):
        m = ""
        if model is not None:
            off = "" if f is None else f" ({100.0 * (f / model[j] - 1.0):+.1f} %)"
            m = f"  model {model[j]:8.3f} Hz{off}"
        if f is None:
            lines.append(f"mode {j + 1}  not seen (too weak, or one frequency with another){m}")
            continue
        dirs = "(" + ", ".join(f"{v if abs(v) >= 5e-4 else 0.0:+.3f}" for v in d) + ")"
        lines.append(f"mode {j + 1}  {f:8.3f} Hz  damping ratio {z:.4f}{m}  direction {dirs}")
    if model is None:
        lines.append(
            "model      none (a reel without cable_ea_n): one frequency, the lowest mode's"
        )
    sh = rep["shaper"]
    lines.append("paste into the robot file:")
    lines.append("[shaper]")
    lines.append(f'type = "{sh["type"]}"')
    lines.append(f"damping_ratio = {sh['damping_ratio']:g}       # the lightest damped mode")
    if "frequency_scale" in sh:
        lines.append(
            f"frequency_scale = {sh['frequency_scale']:g}   # measured / model frequencies"
        )
    else:
        lines.append(f"frequency_hz = {sh['frequency_hz']:g}")
    return "\n".join(lines)


class ZenohLink:
    """`Link` over the CLI's Zenoh session: status and commands by query, the poses by a
    subscriber on `<prefix>/pose`."""

    def __init__(self, session: Any, args: argparse.Namespace) -> None:
        self.session = session
        self.args = args
        self._poses: queue.SimpleQueue[bytes] = queue.SimpleQueue()
        self._sub = session.declare_subscriber(
            f"{args.prefix}/pose", lambda s: self._poses.put(s.payload.to_bytes())
        )

    def close(self) -> None:
        """Undeclare the subscriber."""
        self._sub.undeclare()

    def status(self) -> dict[str, Any]:
        """The daemon's status ({} if it is not an object)."""
        from controller.cli.session import query

        st = query(self.session, f"{self.args.prefix}/status", None, self.args.timeout)
        return st if isinstance(st, dict) else {}

    def command(self, verb: str, payload: dict[str, Any] | None) -> dict[str, Any]:
        """Send `verb` with `payload`; raises Refused with the daemon's reason."""
        from controller.cli.session import query

        reply = query(self.session, f"{self.args.prefix}/cmd/{verb}", payload, self.args.timeout)
        return reply if isinstance(reply, dict) else {}

    def take_samples(self) -> list[dict[str, Any]]:
        """The pose samples received since the last call (undecodable ones dropped)."""
        out: list[dict[str, Any]] = []
        while True:
            try:
                raw = self._poses.get_nowait()
            except queue.Empty:
                return out
            try:
                sample = json.loads(raw)
            except ValueError:
                continue
            if isinstance(sample, dict):
                out.append(sample)

    def pause(self, seconds: float) -> None:
        """Sleep."""
        time.sleep(seconds)


def cmd_resonance(args: argparse.Namespace) -> int:
    """`cablebot resonance X Y Z`: the modes measured from the torque telemetry."""
    from controller.cli.session import InputError, run_with_session
    from controller.core.resonance import ResonanceError

    target = xyz_from_args(args)
    if not all(math.isfinite(v) for v in target):
        print(f"cablebot: position must be three finite numbers, got {target}", file=sys.stderr)
        return exitcodes.REFUSED

    def body(session: Any) -> int:
        link = ZenohLink(session, args)
        try:
            rep = measure(
                link,
                target,
                step_m=args.step,
                seconds=args.seconds,
                log=(lambda _: None) if args.json else lambda m: print(m, flush=True),
            )
        except ResonanceError as exc:
            raise InputError(f"no modes measured: {exc}") from None
        finally:
            link.close()
        print(json.dumps(rep, allow_nan=False) if args.json else format_report(rep))
        return exitcodes.OK

    return run_with_session(args, body)


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `resonance`."""
    from controller.cli.session import add_connection_arguments, positive_seconds

    def metres(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected metres, got {text!r}") from None
        if not (math.isfinite(value) and value > 0.0):
            raise argparse.ArgumentTypeError(f"must be a length in m > 0, got {text}")
        return value

    p = sub.add_parser(
        "resonance",
        help="measure the effector's modes at a position from the drives' torque telemetry and "
        "print a [shaper] to paste",
    )
    add_xyz_arguments(p)
    p.add_argument(
        "--step",
        type=metres,
        default=DEFAULT_STEP_M,
        metavar="M",
        help=f"the excitation move's length in m (default {DEFAULT_STEP_M:g})",
    )
    p.add_argument(
        "--seconds",
        type=positive_seconds,
        default=None,
        metavar="S",
        help=f"how long to record the ringing (default {RECORD_PERIODS} periods of the model's "
        "lowest mode, 3 to 30 s; 15 s without a model)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    add_connection_arguments(p)
    p.set_defaults(func=cmd_resonance)
