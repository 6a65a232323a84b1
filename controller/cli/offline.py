"""Offline kinematics tools that need no daemon: `cablebot ipk` and `cablebot fpk`.

From the configuration's anchors and cables (reel homing offsets play no part):

- `cablebot ipk [--config FILE] X Y Z` prints the cable length per reel (by node id): the
  straight line from anchor to effector, and where the cables stretch (`cable_ea_n`) or sag
  (`cable_mass_kg_per_m`) what the reels pay out for the payload at rest there (the lengths the
  controller commands; equal to the straight lines for rigid, massless cables).
- `cablebot fpk [--config FILE] L1 L2 ...` prints the position and the RMS residual of
  straight-line lengths; with `--paid-out`, of what the reels paid out (stretch and sag as
  configured, the controller's pose estimate).

`--json` prints one JSON object instead. Exit 0 on success; 1 with a message on stderr for a
bad configuration, a non-finite number, a wrong number of lengths, lengths that cannot meet in
one point, or (ipk, unless `--no-limits`) a point outside the configured workspace.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from controller.cli import add_xyz_arguments, exitcodes

EXIT_OK = exitcodes.OK
EXIT_ERROR = exitcodes.REFUSED


def _fail(msg: str) -> int:
    print(f"cablebot: {msg}", file=sys.stderr)
    return EXIT_ERROR


def _load(path: str | None) -> Any:
    """The RobotConfig at `path` (built-in default when None); raises ConfigError."""
    from controller.service.config import load_config

    return load_config(path)


def ipk_lengths(cfg: Any, position_m: tuple[float, float, float]) -> dict[int, float]:
    """Cable length (m) per node id for the effector at `position_m`.

    Raises kinematics.KinematicsError for a non-finite position.
    """
    from controller.core import kinematics

    lengths = kinematics.ipk_point(cfg.geometry, position_m)
    return {int(r.node_id): float(length) for r, length in zip(cfg.reels, lengths, strict=True)}


def paid_out_lengths(cfg: Any, position_m: tuple[float, float, float]) -> tuple[float, ...]:
    """What the reels pay out (m, reel order) to hold the payload at rest at `position_m`:
    the controller's commanded lengths there, with stretch and sag as configured (the
    straight lines for rigid, massless cables).

    Raises kinematics.KinematicsError (its stretch and sag subclasses included) where the
    cables cannot hold the payload there.
    """
    return tuple(float(v) for v in cable_model(cfg).home_lengths_m(position_m))


def cable_model(cfg: Any) -> Any:
    """The controller's `CableModel` of `cfg`: rigid, stretching or heavy cables, with the
    payload's tension rule. Raises KinematicsError / ValueError for an unusable model."""
    from controller.service.cables import CableModel
    from controller.service.config import tension_check

    check = (
        None
        if cfg.tension is None or cfg.payload is None
        else tension_check(cfg.payload, cfg.tension, cfg.geometry, cfg.reels)
    )
    return CableModel.from_config(cfg, check)


def workspace_problem(cfg: Any, position_m: tuple[float, float, float]) -> str | None:
    """Why `position_m` is not an allowed pose of the configured robot (outside the workspace
    or a cable length out of range), or None when it is allowed; the workspace decides.
    Raises nothing for a validated configuration."""
    from controller.core.workspace import Workspace

    return Workspace.from_limits(cfg.limits, cfg.geometry).check_target(position_m)


def cmd_ipk(args: argparse.Namespace) -> int:
    """`cablebot ipk`: print the cable lengths for a position."""
    from controller.core.kinematics import KinematicsError
    from controller.service.config import ConfigError

    p = (float(args.x), float(args.y), float(args.z))
    if not all(math.isfinite(v) for v in p):
        return _fail(f"position must be three finite numbers, got {list(p)}")
    try:
        cfg = _load(args.config)
        lengths = ipk_lengths(cfg, p)
    except (ConfigError, KinematicsError, OSError) as exc:
        return _fail(str(exc))
    problem = None if args.no_limits else workspace_problem(cfg, p)
    paid: tuple[float, ...] | None = None
    paid_problem = None
    try:
        paid = paid_out_lengths(cfg, p)
    except (KinematicsError, ValueError) as exc:
        paid_problem = f"no paid-out lengths there: {exc}"
    if args.json:
        print(
            json.dumps(
                {
                    "position_m": list(p),
                    "node_ids": list(lengths),
                    "cable_lengths_m": list(lengths.values()),
                    "paid_out_m": None if paid is None else list(paid),
                    "in_workspace": problem is None,
                    "problem": problem or paid_problem,
                }
            )
        )
    else:
        print(f"position x={p[0]:+.4f} y={p[1]:+.4f} z={p[2]:+.4f} m")
        modelled = _modelled(cfg)
        if modelled and paid is not None:
            print(f"          straight line  paid out ({modelled})")
            for (node_id, length), out in zip(lengths.items(), paid, strict=True):
                print(f"node {node_id:2d}  {length:.6f} m     {out:.6f} m")
        else:
            for node_id, length in lengths.items():
                print(f"node {node_id:2d}  {length:.6f} m")
    if problem is not None:
        return _fail(f"outside the workspace: {problem} (--no-limits to ignore)")
    if paid_problem is not None:
        return _fail(paid_problem)
    return EXIT_OK


def _modelled(cfg: Any) -> str:
    """What the paid-out lengths allow for ("stretch", "sag", "stretch and sag"), "" when they
    are the straight lines. Raises nothing."""
    parts = []
    if any(r.cable_ea_n is not None for r in cfg.reels):
        parts.append("stretch")
    if any(r.cable_mass_kg_per_m for r in cfg.reels):
        parts.append("sag")
    return " and ".join(parts)


def cmd_fpk(args: argparse.Namespace) -> int:
    """`cablebot fpk`: print the position (and residual) for cable lengths."""
    from controller.core import kinematics
    from controller.service.config import ConfigError

    lengths = [float(v) for v in args.lengths]
    if not all(math.isfinite(v) and v > 0.0 for v in lengths):
        return _fail(f"cable lengths must be finite and > 0, got {args.lengths}")
    try:
        cfg = _load(args.config)
    except (ConfigError, OSError) as exc:
        return _fail(str(exc))
    n = len(cfg.reels)
    if len(lengths) != n:
        ids = ", ".join(str(r.node_id) for r in cfg.reels)
        return _fail(f"expected {n} cable lengths (nodes {ids}), got {len(lengths)}")
    try:
        if args.paid_out:
            pose, residual = cable_model(cfg).pose(lengths, None)
        else:
            res = kinematics.fpk(cfg.geometry, lengths)
            pose, residual = res.position_m, float(res.residual_m)
    except (kinematics.KinematicsError, ValueError) as exc:
        return _fail(f"no position for these lengths: {exc}")
    x, y, z = (float(v) for v in pose)
    if args.json:
        print(
            json.dumps(
                {
                    "position_m": [x, y, z],
                    "residual_m": float(residual),
                    "paid_out": bool(args.paid_out),
                }
            )
        )
    else:
        what = ""
        if args.paid_out:
            what = f"  (paid-out lengths{', ' + _modelled(cfg) if _modelled(cfg) else ''})"
        print(
            f"position x={x:+.6f} y={y:+.6f} z={z:+.6f} m  residual {residual * 1e3:.3f} mm{what}"
        )
    return EXIT_OK


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `ipk` and `fpk`."""
    p = sub.add_parser("ipk", help="cable lengths for a position (offline, no daemon)")
    p.add_argument("--config", default=None, metavar="FILE", help="robot TOML (default built-in)")
    add_xyz_arguments(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--no-limits", action="store_true", help="do not check the point against the workspace"
    )
    p.set_defaults(func=cmd_ipk)

    p = sub.add_parser("fpk", help="position for cable lengths (offline, no daemon)")
    p.add_argument("--config", default=None, metavar="FILE", help="robot TOML (default built-in)")
    p.add_argument("lengths", type=float, nargs="+", metavar="L", help="lengths in m, reel order")
    p.add_argument(
        "--paid-out",
        action="store_true",
        help="the lengths are what the reels paid out: allow for stretch and sag as configured",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_fpk)
