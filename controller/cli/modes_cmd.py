"""`cablebot modes X Y Z [--config FILE] [--json] [--sim]`: the effector's modes at a pose,
offline, from the robot's model (`controller.core.vibration`).

The stiffness comes from every reel's `cable_ea_n` and the tensions statics plans to hold the
payload there; the damping ratios from `[shaper] damping_ratio` (the ropes' damping the
configuration assumes). `--sim` takes the simulator's physical plant instead: `[sim]
cable_ea_n`, `cable_damping_ratio` and the effector's drag (what `cablebot resonance` measures
on the simulated robot). The shaper's delay at the pose follows. A rigid model, a slack cable
or a pose outside the workspace is said (exit 1), never a NaN. JSON: `frequencies_hz`
ascending, `damping_ratios`, `directions` (unit vectors), `tensions_n`, `problem`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from controller.cli import add_xyz_arguments, exitcodes
from controller.cli.shaper_cmd import shaper_name

EXIT_OK = exitcodes.OK
EXIT_ERROR = exitcodes.REFUSED


def _fail(msg: str) -> int:
    print(f"cablebot: {msg}", file=sys.stderr)
    return EXIT_ERROR


def modes_report(cfg: Any, position_m: tuple[float, float, float], sim: bool) -> dict[str, Any]:
    """The JSON-ready answer of `cablebot modes` at `position_m` (the model's, or with `sim`
    the simulator's plant). Raises nothing for a validated configuration: what cannot be
    computed is in "problem" with the modes None."""
    from controller.core.motion.shaper import duration_periods
    from controller.core.statics import StaticsError
    from controller.core.vibration import ModesError, effector_modes
    from controller.service.config import tension_check
    from controller.service.simulated import sim_plant_params

    out: dict[str, Any] = {
        "position_m": list(position_m),
        "source": "sim" if sim else "model",
        "mass_kg": None,
        "cable_ea_n": None,
        "damping_ratio": None,
        "effector_damping_n_s_per_m": 0.0,
        "frequencies_hz": None,
        "damping_ratios": None,
        "directions": None,
        "tensions_n": None,
        "shaper": None,
        "problem": None,
    }
    if cfg.tension is None or cfg.payload is None:
        out["problem"] = "no [payload] mass_kg: no tensions, no modes"
        return out
    check = tension_check(cfg.payload, cfg.tension, cfg.geometry)
    if sim:
        params = sim_plant_params(cfg)
        ea: list[float | None] = list(params.ea_n)
        zeta = params.cable_damping_ratio
        drag = params.effector_damping_n_s_per_m
    else:
        ea = [r.cable_ea_n for r in cfg.reels]
        zeta = cfg.shaper.damping_ratio
        drag = 0.0
    out.update(
        mass_kg=check.mass_kg,
        cable_ea_n=ea,
        damping_ratio=zeta,
        effector_damping_n_s_per_m=drag,
    )
    try:
        tensions = check.solve(position_m).tensions_n
        modes = effector_modes(
            cfg.anchors_m,
            position_m,
            tensions,
            ea,
            check.mass_kg,
            cable_damping_ratio=zeta,
            effector_damping_n_s_per_m=drag,
        )
    except StaticsError as exc:
        out["problem"] = f"the cables cannot hold {check.mass_kg:g} kg there: {exc}"
        return out
    except ModesError as exc:
        hint = "" if sim or None not in ea else " (--sim: the simulator's plant)"
        out["problem"] = f"no modes: {exc}{hint}"
        return out
    out.update(
        frequencies_hz=list(modes.frequencies_hz),
        damping_ratios=list(modes.damping_ratios),
        directions=[[v if abs(v) > 1e-12 else 0.0 for v in d] for d in modes.directions],
        tensions_n=list(modes.tensions_n),
    )
    sc = cfg.shaper
    if sc.enabled:
        per = duration_periods(sc.type) * sc.passes
        freqs = (
            [sc.frequency_hz]
            if sc.frequency_hz is not None
            else [f * sc.frequency_scale for f in modes.frequencies_hz]
        )
        out["shaper"] = {
            "type": sc.type,
            "passes": sc.passes,
            "frequencies_hz": freqs,
            "delay_s": sum(per / f for f in freqs),
        }
    return out


def modes_lines(cfg: Any) -> tuple[list[str], dict[str, Any]]:
    """The check-config lines on the effector's modes (their range over the workspace, from the
    model) and the shaper, and their JSON. Raises nothing for a validated configuration."""
    from controller.core.motion.shaper import duration_periods
    from controller.core.vibration import ModesError
    from controller.service.config import tension_check
    from controller.service.shaping import mode_range

    sc = cfg.shaper
    data: dict[str, Any] = {"modes": None, "shaper": {"type": sc.type}}
    lines = []
    rng = None
    if cfg.tension is None or cfg.payload is None:
        lines.append("modes      no [payload]: no model of the modes")
    elif any(r.cable_ea_n is None for r in cfg.reels):
        lines.append(
            "modes      rigid cables (no [[reels]] cable_ea_n): no model of the modes "
            "(`cablebot modes --sim` gives the simulator's)"
        )
    else:
        check = tension_check(cfg.payload, cfg.tension, cfg.geometry)
        try:
            rng = mode_range(cfg, check, sc.damping_ratio)
        except (ModesError, ValueError) as exc:
            lines.append(f"modes      none: {exc}")
        if rng is None:
            if not lines:
                lines.append("modes      none: no pose of the workspace has modes")
        else:
            parts = ", ".join(
                f"{lo:.3g}..{hi:.3g} Hz" for lo, hi in zip(rng.low_hz, rng.high_hz, strict=True)
            )
            lines.append(
                f"modes      {parts} over {rng.points} poses of the workspace ({check.mass_kg:g} "
                f"kg), damping ratio {min(rng.low_damping):.3g}..{max(rng.high_damping):.3g}"
            )
            data["modes"] = {
                "low_hz": list(rng.low_hz),
                "high_hz": list(rng.high_hz),
                "low_damping": list(rng.low_damping),
                "high_damping": list(rng.high_damping),
                "points": rng.points,
                "skipped": rng.skipped,
            }
    if not sc.enabled:
        lines.append("shaper     off (`[shaper] type`; on by default where the modes are known)")
        return lines, data
    per = duration_periods(sc.type) * sc.passes
    data["shaper"] = {
        "type": sc.type,
        "damping_ratio": sc.damping_ratio,
        "frequency_hz": sc.frequency_hz,
        "frequency_scale": sc.frequency_scale,
        "passes": sc.passes,
    }
    if sc.frequency_hz is not None:
        delay = per / sc.frequency_hz
        lines.append(
            f"shaper     {shaper_name(sc.type, sc.passes)} at {sc.frequency_hz:g} Hz everywhere, "
            f"damping ratio "
            f"{sc.damping_ratio:g}: delays every move by {delay * 1e3:.3g} ms"
        )
        data["shaper"]["delay_s"] = [delay, delay]
    elif rng is not None:
        k = sc.frequency_scale
        lo = sum(per / (f * k) for f in rng.high_hz)
        hi = sum(per / (f * k) for f in rng.low_hz)
        scale = "" if k == 1.0 else f" x {k:g}"
        lines.append(
            f"shaper     {shaper_name(sc.type, sc.passes)} on the model's three modes at the "
            f"set-point{scale}, damping "
            f"ratio {sc.damping_ratio:g}: delays a move by {lo:.3g}..{hi:.3g} s"
        )
        data["shaper"]["delay_s"] = [lo, hi]
    return lines, data


def _direction(d: list[float]) -> str:
    return "(" + ", ".join(f"{v if abs(v) >= 5e-4 else 0.0:+.3f}" for v in d) + ")"


def cmd_modes(args: argparse.Namespace) -> int:
    """`cablebot modes`: the effector's natural frequencies, damping and directions."""
    from controller.cli.offline import workspace_problem
    from controller.service.config import ConfigError, load_config

    p = (float(args.x), float(args.y), float(args.z))
    if not all(math.isfinite(v) for v in p):
        return _fail(f"position must be three finite numbers, got {list(p)}")
    try:
        cfg = load_config(args.config)
    except (ConfigError, OSError, ValueError) as exc:
        return _fail(str(exc))
    geometric = workspace_problem(cfg, p)
    if geometric is not None:
        rep: dict[str, Any] = {
            "position_m": list(p),
            "problem": f"outside the workspace: {geometric}",
        }
    else:
        rep = modes_report(cfg, p, args.sim)
    if args.json:
        print(json.dumps(rep, allow_nan=False))
    elif rep.get("frequencies_hz") is not None:
        ea = rep["cable_ea_n"]
        ea_text = f"{ea[0]:g} N" if len(set(ea)) == 1 else ", ".join(f"{v:g}" for v in ea) + " N"
        where = "the simulator's plant" if args.sim else "the model"
        drag = rep["effector_damping_n_s_per_m"]
        print(
            f"position x={p[0]:+.4f} y={p[1]:+.4f} z={p[2]:+.4f} m, payload {rep['mass_kg']:g} kg, "
            f"cable EA {ea_text}, ropes' damping ratio {rep['damping_ratio']:g}"
            f"{f', drag {drag:g} N s/m' if drag else ''} ({where})"
        )
        for j, (f, z, d) in enumerate(
            zip(rep["frequencies_hz"], rep["damping_ratios"], rep["directions"], strict=True)
        ):
            print(f"mode {j + 1}  {f:8.3f} Hz  damping ratio {z:.4f}  direction {_direction(d)}")
        sh = rep.get("shaper")
        if sh is not None:
            parts = " + ".join(f"{cfg_delay:.3f}" for cfg_delay in _delays(sh))
            name = shaper_name(sh["type"], int(sh.get("passes", 1)))
            print(f"shaper  {name}: delays a move by {parts} = {sh['delay_s']:.3f} s here")
        else:
            print('shaper  off ([shaper] type = "off", or no model of the modes)')
    if rep.get("problem") is not None:
        return _fail(str(rep["problem"]))
    return EXIT_OK


def _delays(shaper: dict[str, Any]) -> list[float]:
    """Each stage's delay (s) of a `modes_report` shaper entry."""
    from controller.core.motion.shaper import duration_periods

    per = duration_periods(shaper["type"]) * int(shaper.get("passes", 1))
    return [per / f for f in shaper["frequencies_hz"]]


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `modes`."""
    p = sub.add_parser(
        "modes",
        help="the effector's natural frequencies, damping and mode directions at a position "
        "(offline, no daemon)",
    )
    p.add_argument("--config", default=None, metavar="FILE", help="robot TOML (default built-in)")
    add_xyz_arguments(p)
    p.add_argument(
        "--sim",
        action="store_true",
        help="the simulator's physical plant ([sim] cable_ea_n, its ropes and drag) instead of "
        "the model ([[reels]] cable_ea_n, [shaper] damping_ratio)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_modes)
