"""Offline statics tools that need no daemon: `cablebot statics` and `cablebot workspace`.

Both take the payload and the tension limits from the configuration (`[payload]`,
`[limits] min_tension_n / max_tension_n / tension_margin_n`, the reels' `max_torque_nm`);
`--mass-kg` overrides the payload.

- `cablebot statics [--config FILE] X Y Z` prints the tension each cable needs to hold the
  payload still at (X, Y, Z), the margin to the limits and the cable that limits it. Exit 1
  (with the reason on stderr, and in the JSON's "problem") when the controller would refuse the
  pose: outside the geometric workspace (unless `--no-limits`; this reason comes first) or a
  tension closer than `tension_margin_n` to a limit.
- `cablebot workspace [--config FILE] [--step M] [--png FILE]` samples the geometric
  workspace (`controller.core.workspace.Workspace`: the anchors' footprint shrunk by
  `xy_margin_m`, the z band, the cable lengths) on a grid of cells of about `--step` metres and
  prints the part where the payload can be held within the tension limits and their margin:
  its volume, the sampled geometric volume, and a bound on the sampling error (the volume of
  the cells the boundary crosses). `--png` draws horizontal slices at several heights.

`--json` prints one JSON object instead. Cable numbers are 1-based, as in every message.
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

DEFAULT_CELLS_PER_SPAN = 100
"""Without `--step`, the longest side of the workspace box is cut into about this many cells."""
DEFAULT_CELLS_PER_SPAN_SAG = 40
"""The same with heavy cables (every point is a solve of the statics with sag, about 0.3 ms)."""
MAX_CELLS = 20_000_000
"""`--step` may not ask for more cells than this (memory and time)."""
SLICES = 6
"""Horizontal slices drawn by `--png`."""


def _fail(msg: str) -> int:
    print(f"cablebot: {msg}", file=sys.stderr)
    return EXIT_ERROR


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(v) and v > 0.0):
        raise argparse.ArgumentTypeError(f"must be finite and > 0, got {text!r}")
    return v


def tension_check_of(cfg: Any, mass_kg: float | None) -> Any:
    """The `TensionCheck` of the configuration (payload `mass_kg` if given; with heavy
    cables the rule with their weight, `SagTensionCheck`).

    Raises ValueError naming what is missing when the configuration has no `[payload]` (and
    no mass is given), and StaticsInputError for a bad mass.
    """
    from controller.service.config import PayloadConfig, tension_check

    if cfg.tension is None:
        raise ValueError(
            f"{cfg.source} has no [payload] mass_kg and tension limits: nothing to solve "
            "(see the Statics section of docs/statics-and-calibration.md)"
        )
    payload = cfg.payload if mass_kg is None else PayloadConfig(mass_kg=mass_kg)
    return tension_check(payload, cfg.tension, cfg.geometry, cfg.reels)


def statics_report(cfg: Any, check: Any, position_m: tuple[float, float, float]) -> dict[str, Any]:
    """The JSON-ready answer of `cablebot statics` for `position_m` (see `cmd_statics`).

    "tensions_n" are what the reels carry: the tension at each cable's anchor end, which
    with heavy cables (`cable_mass_kg_per_m`) is the one at its effector end
    ("effector_tensions_n") plus about the cable's weight over its rise ("anchor_tensions_n";
    the same for massless cables).  Raises nothing: a pose where no distribution exists gives
    tensions and margin None and the reason in "problem".
    """
    from controller.core.statics import StaticsError

    lim = check.statics
    out: dict[str, Any] = {
        "position_m": list(position_m),
        "mass_kg": check.mass_kg,
        "node_ids": [int(r.node_id) for r in cfg.reels],
        "min_tension_n": lim.t_min_n,
        "max_tension_n": lim.t_max_n,
        "max_tension_source": check.max_source,
        "tension_margin_n": check.margin_n,
    }
    sag = getattr(check, "sag", None)
    try:
        if sag is not None:
            sol = sag.solve(position_m)
            res = check.tensions(sol)
            ends = (list(sol.effector_tensions_n), list(sol.anchor_tensions_n))
        else:
            res = check.solve(position_m)
            ends = (list(res.tensions_n), list(res.tensions_n))
    except StaticsError as exc:
        out.update(
            tensions_n=None,
            effector_tensions_n=None,
            anchor_tensions_n=None,
            feasible=False,
            margin_n=None,
            limiting_cable=None,
            limiting_node_id=None,
            limiting_bound=None,
            within_margin=False,
            problem=f"the cables cannot hold {check.mass_kg:g} kg there: {exc}",
        )
        return out
    out.update(
        tensions_n=list(res.tensions_n),
        effector_tensions_n=ends[0],
        anchor_tensions_n=ends[1],
        feasible=res.feasible,
        margin_n=res.margin_n,
        limiting_cable=res.limiting_cable + 1,
        limiting_node_id=int(cfg.reels[res.limiting_cable].node_id),
        limiting_bound=res.limiting_bound,
        within_margin=res.margin_n >= check.margin_n,
        problem=check.reason(res),
    )
    return out


def cmd_statics(args: argparse.Namespace) -> int:
    """`cablebot statics`: the cable tensions that hold the payload still at a position."""
    from controller.cli.offline import workspace_problem
    from controller.core.statics import StaticsInputError
    from controller.service.config import ConfigError, load_config

    p = (float(args.x), float(args.y), float(args.z))
    if not all(math.isfinite(v) for v in p):
        return _fail(f"position must be three finite numbers, got {list(p)}")
    try:
        cfg = load_config(args.config)
        check = tension_check_of(cfg, args.mass_kg)
    except (ConfigError, OSError, StaticsInputError, ValueError) as exc:
        return _fail(str(exc))
    rep = statics_report(cfg, check, p)
    geometric = None if args.no_limits else workspace_problem(cfg, p)
    rep["in_workspace"] = geometric is None if not args.no_limits else None
    if geometric is not None:  # the geometric refusal comes first, as in the controller
        rep["problem"] = f"outside the workspace: {geometric} (--no-limits to ignore)"
    if args.json:
        print(json.dumps(rep, allow_nan=False))
    else:
        heavy = getattr(check, "sag", None) is not None
        weight = ""
        if heavy:
            masses = sorted({float(r.cable_mass_kg_per_m or 0.0) for r in cfg.reels})
            weight = f" and the cables' weight ({', '.join(f'{m:g}' for m in masses)} kg/m)"
        print(
            f"position x={p[0]:+.4f} y={p[1]:+.4f} z={p[2]:+.4f} m, payload "
            f"{check.mass_kg:g} kg{weight}, limits {check.statics.t_min_n:g}.."
            f"{check.statics.t_max_n:.4g} N ({check.max_source}), margin {check.margin_n:g} N"
        )
        if rep["tensions_n"] is not None and heavy:
            print("                   at the effector   at the anchor")
            rows = zip(
                rep["node_ids"], rep["effector_tensions_n"], rep["anchor_tensions_n"], strict=True
            )
            for i, (node, t0, t1) in enumerate(rows):
                print(f"cable {i + 1}  node {node:2d}  {t0:12.4f} N  {t1:12.4f} N")
        elif rep["tensions_n"] is not None:
            for i, (node, t) in enumerate(zip(rep["node_ids"], rep["tensions_n"], strict=True)):
                print(f"cable {i + 1}  node {node:2d}  {t:10.4f} N")
        if rep["tensions_n"] is not None:
            bound = "min" if rep["limiting_bound"] == "min" else "max"
            end = ""
            if heavy:
                end = " at the effector" if bound == "min" else " at the anchor"
            print(
                f"margin {rep['margin_n']:.4f} N (cable {rep['limiting_cable']}{end}, to the "
                f"{bound} limit){'' if rep['within_margin'] else ': too close'}"
            )
    if rep["problem"] is not None:
        return _fail(str(rep["problem"]))
    return EXIT_OK


def workspace_map(cfg: Any, check: Any, step_m: float | None, straight: bool = False) -> Any:
    """`controller.core.feasible.FeasibleWorkspace` of the geometric workspace for `check`.

    The grid spans the workspace's bounding box (`Workspace.box`); a cell counts where its
    centre is inside the geometric limits (`Workspace.inside_points`) and the payload can be
    held there with every tension `check.margin_n` inside the limits: with heavy cables by
    the rule with their weight (a solve per point: a coarser default grid,
    `DEFAULT_CELLS_PER_SPAN_SAG`), or with `straight` by the straight cables' rule. Raises
    StaticsInputError for a step that gives too many cells, WorkspaceError (a ValueError) for
    an empty workspace.
    """
    from controller.core.feasible import feasible_workspace
    from controller.core.statics import StaticsInputError
    from controller.core.workspace import Workspace

    workspace = Workspace.from_limits(cfg.limits, cfg.geometry)
    box = workspace.box()
    spans = [hi - lo for lo, hi in box]
    heavy = getattr(check, "sag", None) is not None and not straight
    per_span = DEFAULT_CELLS_PER_SPAN_SAG if heavy else DEFAULT_CELLS_PER_SPAN
    step = max(spans) / per_span if step_m is None else step_m
    cells = math.prod(max(1, round(s / step)) for s in spans)
    if cells > MAX_CELLS:
        raise StaticsInputError(
            f"--step {step:g} m gives {cells} cells (at most {MAX_CELLS}); use a larger step"
        )
    t_lo = check.statics.t_min_n + check.margin_n
    t_hi = check.statics.t_max_n - check.margin_n
    return feasible_workspace(
        cfg.geometry.anchors_m,
        box[0],
        box[1],
        box[2],
        step,
        check.mass_kg,
        t_lo,
        t_hi,
        inside=workspace.inside_points,
        margins=check.margins if heavy else None,
    )


def workspace_report(check: Any, ws: Any, step_m: float) -> dict[str, Any]:
    """The JSON-ready summary of `cablebot workspace`. Raises nothing."""
    region = ws.region_volume_m3
    return {
        "mass_kg": check.mass_kg,
        "min_tension_n": check.statics.t_min_n,
        "max_tension_n": check.statics.t_max_n,
        "max_tension_source": check.max_source,
        "tension_margin_n": check.margin_n,
        "step_m": step_m,
        "cell_m": list(ws.cell_m),
        "cells": int(ws.feasible.size),
        "volume_m3": ws.volume_m3,
        "uncertainty_m3": ws.uncertainty_m3,
        "geometric_volume_m3": region,
        "feasible_fraction": ws.volume_m3 / region if region > 0.0 else 0.0,
        "x_m": [float(ws.xs_m[0] - ws.cell_m[0] / 2), float(ws.xs_m[-1] + ws.cell_m[0] / 2)],
        "y_m": [float(ws.ys_m[0] - ws.cell_m[1] / 2), float(ws.ys_m[-1] + ws.cell_m[1] / 2)],
        "z_m": [float(ws.zs_m[0] - ws.cell_m[2] / 2), float(ws.zs_m[-1] + ws.cell_m[2] / 2)],
    }


def _volume(v: float) -> str:
    return f"{v:,.0f}" if abs(v) >= 100.0 else f"{v:.4g}"


def draw_slices(
    cfg: Any, check: Any, ws: Any, path: str, slices: int = SLICES, straight: Any = None
) -> list[float]:
    """Write a PNG of `slices` horizontal slices of the map (tension margin in colour where the
    payload can be held, grey where geometry allows but the tensions do not; with the straight
    cables' map `straight`, red where it allows what the map refuses); returns the slice
    heights. Raises ImportError without matplotlib (the `plot` extra), OSError if the file
    cannot be written."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from controller.core.workspace import Workspace

    limits = Workspace.from_limits(cfg.limits, cfg.geometry)
    nz = ws.zs_m.size
    idx = sorted({round(k * (nz - 1) / max(1, slices - 1)) for k in range(slices)})
    cols = min(3, len(idx))
    rows = math.ceil(len(idx) / cols)
    aspect = (ws.ys_m[-1] - ws.ys_m[0] + ws.cell_m[1]) / (ws.xs_m[-1] - ws.xs_m[0] + ws.cell_m[0])
    fig, axes = plt.subplots(
        rows,
        cols,
        figsize=(4.2 * cols + 1.2, rows * (4.2 * min(1.2, max(0.45, aspect)) + 1.1) + 0.6),
        squeeze=False,
        layout="constrained",
    )
    gx, gy = np.meshgrid(ws.xs_m, ws.ys_m, indexing="ij")
    extent = (
        ws.xs_m[0] - ws.cell_m[0] / 2,
        ws.xs_m[-1] + ws.cell_m[0] / 2,
        ws.ys_m[0] - ws.cell_m[1] / 2,
        ws.ys_m[-1] + ws.cell_m[1] / 2,
    )
    # margin_n is relative to the shrunk limits: add the configured margin back for display
    shown = ws.margin_n + check.margin_n
    vmax = float(np.max(np.where(ws.feasible, shown, -np.inf), initial=1.0))
    anchors = np.asarray(cfg.geometry.anchors_m)
    footprint = [*cfg.geometry.footprint_m, cfg.geometry.footprint_m[0]]
    image = None
    heights: list[float] = []
    for ax, k in zip(axes.flat, idx, strict=False):
        z = float(ws.zs_m[k])
        heights.append(z)
        pts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, z)], axis=1)
        inside = limits.inside_points(pts).reshape(gx.shape)
        feas = ws.feasible[:, :, k]
        ax.imshow(
            np.where(inside & ~feas, 1.0, np.nan).T,
            origin="lower",
            extent=extent,
            cmap="Greys",
            vmin=0.0,
            vmax=2.5,
            interpolation="nearest",
        )
        if straight is not None:
            ax.imshow(
                np.where(straight.feasible[:, :, k] & ~feas, 1.0, np.nan).T,
                origin="lower",
                extent=extent,
                cmap="Reds",
                vmin=0.0,
                vmax=1.2,
                interpolation="nearest",
            )
        image = ax.imshow(
            np.where(feas, shown[:, :, k], np.nan).T,
            origin="lower",
            extent=extent,
            cmap="viridis",
            vmin=check.margin_n,
            vmax=max(vmax, check.margin_n + 1e-9),
            interpolation="nearest",
        )
        ax.plot([p[0] for p in footprint], [p[1] for p in footprint], "k-", lw=0.8)
        ax.plot(anchors[:, 0], anchors[:, 1], "r^", ms=6)
        share = float(feas.sum()) / max(1, int(inside.sum()))
        ax.set_title(f"z = {z:.3g} m: {100 * share:.0f} % of the slice", fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)", fontsize=8)
        ax.set_ylabel("y (m)", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(idx) :]:
        ax.set_visible(False)
    if image is not None:
        bar = fig.colorbar(image, ax=axes.ravel().tolist(), shrink=0.8)
        bar.set_label("tension margin (N): distance of the nearest cable to a limit")
    red = "; red: straight cables would allow" if straight is not None else ""
    heavy = " with the cables' weight" if straight is not None else ""
    fig.suptitle(
        f"{cfg.name}: {check.mass_kg:g} kg held{heavy} within {check.statics.t_min_n:g}.."
        f"{check.statics.t_max_n:.4g} N, {check.margin_n:g} N inside; grey: geometric "
        f"workspace the tensions exclude{red}\nfeasible {_volume(ws.volume_m3)} ± "
        f"{_volume(ws.uncertainty_m3)} m³ of {_volume(ws.region_volume_m3)} m³",
        fontsize=10,
    )
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return heights


def cmd_workspace(args: argparse.Namespace) -> int:
    """`cablebot workspace`: the tension-feasible part of the geometric workspace."""
    from controller.core.statics import StaticsInputError
    from controller.core.workspace import Workspace
    from controller.service.config import ConfigError, load_config

    straight = None
    try:
        cfg = load_config(args.config)
        check = tension_check_of(cfg, args.mass_kg)
        step_m = args.step
        if getattr(check, "sag", None) is not None:
            if step_m is None:
                box = Workspace.from_limits(cfg.limits, cfg.geometry).box()
                step_m = max(hi - lo for lo, hi in box) / DEFAULT_CELLS_PER_SPAN_SAG
            straight = workspace_map(cfg, check, step_m, straight=True)
        ws = workspace_map(cfg, check, step_m)
    except (ConfigError, OSError, StaticsInputError, ValueError) as exc:
        return _fail(str(exc))
    step = step_m if step_m is not None else max(ws.cell_m)
    rep = workspace_report(check, ws, step)
    if straight is not None:
        rep.update(sag_comparison(straight, ws))
    if args.png:
        try:
            rep["png"] = args.png
            rep["slices_z_m"] = draw_slices(cfg, check, ws, args.png, straight=straight)
        except ImportError as exc:
            return _fail(f"--png needs matplotlib (pip install 'cablebot[plot]'): {exc}")
        except OSError as exc:
            return _fail(f"cannot write {args.png}: {exc}")
    if args.json:
        print(json.dumps(rep, allow_nan=False))
        return EXIT_OK
    frac = rep["feasible_fraction"]
    print(
        f"payload {check.mass_kg:g} kg, tensions {check.statics.t_min_n:g}.."
        f"{check.statics.t_max_n:.4g} N ({check.max_source}), {check.margin_n:g} N inside"
    )
    cx, cy, cz = ws.cell_m
    print(
        f"grid     {ws.xs_m.size} x {ws.ys_m.size} x {ws.zs_m.size} cells of "
        f"{cx:.4g} x {cy:.4g} x {cz:.4g} m"
    )
    print(f"geometric workspace  {rep['geometric_volume_m3']:.6g} m³ (sampled)")
    print(
        f"tension-feasible     {ws.volume_m3:.6g} m³ ± {ws.uncertainty_m3:.3g} m³ "
        f"({100 * frac:.1f} %)"
    )
    if straight is not None:
        print(
            f"straight cables      {rep['straight_volume_m3']:.6g} m³ by the rule without "
            "the cables' weight"
        )
        for key, what in (
            ("straight_only", "the straight rule allows, the catenary refuses"),
            ("sag_only", "the catenary allows, the straight rule refuses"),
        ):
            vol = rep[f"{key}_m3"]
            z = rep[f"{key}_z_m"]
            where = "" if z is None else f" (z {z[0]:.3g}..{z[1]:.3g} m)"
            print(f"  {what}: {vol:.6g} m³{where}")
    if args.png:
        print(f"slices at z = {', '.join(f'{z:.3g}' for z in rep['slices_z_m'])} m: {args.png}")
    return EXIT_OK


def sag_comparison(straight: Any, sag: Any) -> dict[str, Any]:
    """Where the straight cables' tension rule and the rule with the cables' weight disagree
    on one grid: the volume each allows that the other refuses, and its height range (None:
    nowhere). Raises nothing."""
    import numpy as np

    out: dict[str, Any] = {"straight_volume_m3": straight.volume_m3}
    cell = sag.cell_volume_m3
    for key, cells in (
        ("straight_only", straight.feasible & ~sag.feasible),
        ("sag_only", sag.feasible & ~straight.feasible),
    ):
        ks = np.flatnonzero(cells.any(axis=(0, 1)))
        out[f"{key}_m3"] = float(cells.sum()) * cell
        out[f"{key}_z_m"] = (
            None if ks.size == 0 else [float(sag.zs_m[ks[0]]), float(sag.zs_m[ks[-1]])]
        )
    return out


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `statics` and `workspace`."""
    p = sub.add_parser(
        "statics", help="cable tensions that hold the payload at a position (offline, no daemon)"
    )
    p.add_argument("--config", default=None, metavar="FILE", help="robot TOML (default built-in)")
    add_xyz_arguments(p)
    p.add_argument("--mass-kg", type=_positive, default=None, help="payload instead of [payload]")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--no-limits", action="store_true", help="do not check the point against the workspace"
    )
    p.set_defaults(func=cmd_statics)

    p = sub.add_parser(
        "workspace",
        help="the tension-feasible part of the workspace: volume, slices (offline, no daemon)",
    )
    p.add_argument("--config", default=None, metavar="FILE", help="robot TOML (default built-in)")
    p.add_argument(
        "--step",
        type=_positive,
        default=None,
        metavar="M",
        help=f"grid step in m (default: the box's longest side / {DEFAULT_CELLS_PER_SPAN})",
    )
    p.add_argument("--mass-kg", type=_positive, default=None, help="payload instead of [payload]")
    p.add_argument(
        "--png", default=None, metavar="FILE", help="draw horizontal slices (matplotlib)"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_workspace)
