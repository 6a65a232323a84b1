"""The layouts section: statics and FPK per call for 3, 4, 5 and 8 cables, hanging and among
their anchors, against the paper robot's four cables in the same run.

Each layout is timed at random poses of its workspace (`statics_us`, `fpk_us`: every call
starts afresh, as the `statics_us` and `fpk4_us` figures of the statics and kinematics
sections; the statics where the payload is held, the FPK anywhere) and along a path in 1 mm
steps (`statics_tick_us`, `fpk_tick_us`: the loop's calls, each a tick after the last; the FPK
seeded by the last pose). The FPK's lengths carry 1 mm of
noise. Ratios are to the paper robot's figures of the same kind (random poses to random poses,
ticks to ticks), timed interleaved with them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from controller.cli.bench.settings import (
    LAYOUT_KEYS,
    LAYOUTS,
    LENGTH_NOISE_M,
    SEED,
    TARGET_LAYOUT_OVER_PAPER4,
    BenchError,
    Plan,
)
from controller.cli.bench.table import Row
from controller.cli.bench.timing import interleaved


def _layout(name: str) -> tuple[Any, Any, float, Any]:
    """(geometry, CableStatics, payload kg, Workspace) of a benchmark layout."""
    import numpy as np

    from controller.cli.configs import find_example
    from controller.core.kinematics import Geometry
    from controller.core.statics import CableStatics
    from controller.core.workspace import Workspace
    from controller.service.config import default_config, load_config

    if name in ("paper-4", "hangprinter-4", "hangprinter-5"):
        files = {"hangprinter-4": "hangprinter-v4.toml", "hangprinter-5": "hangprinter-5.toml"}
        cfg = default_config() if name == "paper-4" else load_config(find_example(files[name]))
        assert cfg.payload is not None and cfg.tension is not None
        statics = CableStatics(cfg.anchors_m, cfg.tension.min_n, cfg.tension.max_n)
        ws = Workspace.from_limits(cfg.limits, cfg.geometry)
        return cfg.geometry, statics, cfg.payload.mass_kg, ws
    if name == "triangle-3":
        k = np.arange(3) * 2.0 * math.pi / 3.0
        anchors = np.column_stack([1.2 * np.cos(k), 1.2 * np.sin(k), np.full(3, 2.0)])
        geom = Geometry(anchors)
        floor = 0.0
    elif name == "cube-8":
        anchors = np.array(
            [[x, y, z] for x in (-1.2, 1.2) for y in (-1.0, 1.0) for z in (-0.1, 2.1)]
        )
        geom = Geometry(anchors, hanging=False)
        floor = 0.0
    else:
        raise BenchError(f"unknown layout {name}")
    ws = Workspace(
        geom,
        xy_margin_m=0.15,
        floor_z_m=floor,
        top_margin_m=0.2 if name == "cube-8" else 0.5,
        min_cable_m=0.05,
        max_cable_m=10.0,
        max_cable_speed_mps=1.0,
    )
    return geom, CableStatics(anchors, 2.0, 120.0), 1.0, ws


def _poses(ws: Any, statics: Any, mass: float, n: int, seed: int, held: bool) -> Any:
    """`n` random poses of the workspace (with `held`, only where the payload is held: a
    pose the tension check refuses is not one the loop plans)."""
    import numpy as np

    rng = np.random.default_rng(seed)
    (x0, x1), (y0, y1), (z0, z1) = ws.box()
    out: list[Any] = []
    while len(out) < n:
        pts = rng.uniform([x0, y0, z0], [x1, y1, z1], (4 * n, 3))
        pts = pts[ws.inside_points(pts)]
        if held:
            _, margin, _, limiting = statics.solve_batch(pts, mass)
            pts = pts[(limiting >= 0) & (margin > 0.0)]
        out.extend(pts.tolist())
    return np.array(out[:n])


def bench_layouts(repeats: int, n_poses: int) -> dict[str, dict[str, float]]:
    """Microseconds per call of each layout's statics and FPK (at random poses and along a
    path a tick apart) and their ratios to the paper robot's (the keys of `LAYOUT_KEYS` for
    each of `LAYOUTS`). Raises BenchError if a figure is not finite and positive or the FPK
    of a robot among its anchors misses a pose by more than 2 cm (its mirror image)."""
    import numpy as np

    from controller.core.kinematics import fpk, ipk

    sides: list[Callable[[], object]] = []
    for k, name in enumerate(LAYOUTS):
        geom, statics, mass, ws = _layout(name)
        rand = _poses(ws, statics, mass, n_poses, SEED + 20 + k, True)
        anywhere = _poses(ws, statics, mass, n_poses, SEED + 30 + k, False)
        a, b = rand[0], rand[1]
        steps = max(2, n_poses)
        direction = (b - a) / np.linalg.norm(b - a)
        path = np.array([a + 0.001 * i * direction for i in range(steps)])  # 1 mm steps
        rng = np.random.default_rng(SEED + 40 + k)
        noisy = ipk(geom, anywhere) + rng.normal(0.0, LENGTH_NOISE_M, (n_poses, geom.n_cables))
        along = ipk(geom, path) + rng.normal(0.0, LENGTH_NOISE_M, (len(path), geom.n_cables))
        for lengths, truth in ((noisy, anywhere), (along, path)) if not geom.hanging else ():
            for row, p in zip(lengths, truth, strict=True):
                if math.dist(fpk(geom, row.tolist()).position_m, p) > 0.02:
                    raise BenchError(f"{name}: FPK missed {p.tolist()} by more than 2 cm")
        rand_t = [tuple(p) for p in rand.tolist()]
        path_t = [tuple(p) for p in path.tolist()]
        noisy_l = noisy.tolist()
        along_l = along.tolist()
        seeds = [path_t[0], *path_t[:-1]]

        def st_rand(s: Any = statics, pts: Any = rand_t, m: float = mass) -> None:
            for p in pts:
                s.solve(p, m)

        def st_path(s: Any = statics, pts: Any = path_t, m: float = mass) -> None:
            for p in pts:
                s.solve(p, m)

        def fk_rand(g: Any = geom, rows: Any = noisy_l) -> None:
            for row in rows:
                fpk(g, row)

        def fk_path(g: Any = geom, rows: Any = along_l, sd: Any = seeds) -> None:
            for row, seed in zip(rows, sd, strict=True):
                fpk(g, row, seed)

        sides += [st_rand, st_path, fk_rand, fk_path]
    t = interleaved(sides, repeats)
    out: dict[str, dict[str, float]] = {}
    for k, name in enumerate(LAYOUTS):
        i = 4 * k
        fig = {
            "statics_us": t.cpu(i, n_poses) / 1e3,
            "statics_tick_us": t.cpu(i + 1, n_poses) / 1e3,
            "fpk_us": t.cpu(i + 2, n_poses) / 1e3,
            "fpk_tick_us": t.cpu(i + 3, n_poses) / 1e3,
            "statics_over_paper4": t.ratio(i, 0),
            "fpk_over_paper4": t.ratio(i + 2, 2),
            "statics_tick_over_paper4": t.ratio(i + 1, 1),
            "fpk_tick_over_paper4": t.ratio(i + 3, 3),
        }
        for key in LAYOUT_KEYS:
            if not (math.isfinite(fig[key]) and fig[key] > 0.0):
                raise BenchError(f"layouts: {name} {key} is {fig[key]!r}")
        out[name] = fig
    return out


def measure_layouts(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """The layouts section's JSON figures and table rows; the eight-cable robot's statics and
    FPK have a target: at most `TARGET_LAYOUT_OVER_PAPER4` times the paper robot's, at random
    poses and a tick after the last. Raises BenchError."""
    log("layouts (statics and FPK of 3, 4, 5 and 8 cables) ...")
    f = bench_layouts(p.statics_repeats, p.statics_poses)
    rep = f"median of {p.statics_repeats} x {p.statics_poses} poses"
    rows = []
    for name in LAYOUTS:
        for key in LAYOUT_KEYS:
            ratio = key.endswith("_over_paper4")
            target = ratio and name == "cube-8"
            rows.append(
                Row(
                    f"layouts.{name}.{key}",
                    f[name][key],
                    "ratio" if ratio else "us",
                    f"<= {TARGET_LAYOUT_OVER_PAPER4:g}" if target else "",
                    f[name][key] <= TARGET_LAYOUT_OVER_PAPER4 if target else None,
                    rep + ("; interleaved with paper-4" if ratio else ""),
                )
            )
    return f, rows
