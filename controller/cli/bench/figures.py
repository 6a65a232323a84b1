"""The micro-benchmarks: three-spheres and N-cable FPK, the batch, statics, the
physical simulator's real-time factor, the receive path (see `controller.cli.bench`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import replace
from typing import Any

from controller.cli.bench.settings import LENGTH_NOISE_M, SEED, BenchError
from controller.cli.bench.timing import _median, interleaved


def bench_three_spheres(repeats: int, calls: int) -> dict[str, float]:
    """Scalar simplified vs general three-spheres call; microseconds per call and their ratio."""
    from controller.core import kinematics as kin

    anchors = kin.paper_anchors()
    c1, c2, c3 = (tuple(float(v) for v in anchors[i]) for i in range(3))
    geom = kin.Geometry(anchors)
    lengths = kin.ipk(geom, (3.0, -4.0, 2.5))
    r1, r2, r3 = (float(lengths[i]) for i in range(3))
    simplified = kin.three_spheres_equal_height
    general = kin.three_spheres
    a = simplified(c1, c2, c3, r1, r2, r3)
    b = general(c1, c2, c3, r1, r2, r3)
    if math.dist(a, b) > 1e-9:
        raise BenchError(f"simplified {a} and general {b} three-spheres disagree")

    def run_simplified() -> None:
        f = simplified
        for _ in itertools.repeat(None, calls):
            f(c1, c2, c3, r1, r2, r3)

    def run_general() -> None:
        f = general
        for _ in itertools.repeat(None, calls):
            f(c1, c2, c3, r1, r2, r3)

    t = interleaved([run_simplified, run_general], repeats)
    return {
        "fpk_simplified_us": t.cpu(0, calls) / 1e3,
        "fpk_general_us": t.cpu(1, calls) / 1e3,
        "fpk_simplified_over_general": t.ratio(0, 1),
        "fpk_simplified_wall_us": t.wall(0, calls) / 1e3,
        "fpk_general_wall_us": t.wall(1, calls) / 1e3,
    }


def _workspace_poses(cfg: Any, n: int, seed: int) -> Any:
    """`n` random points in the workspace's box (`Workspace.box`), which for the rectangular
    paper robot is the workspace itself.

    Raises BenchError if the box is not inside the workspace (a non-rectangular layout).
    """
    import numpy as np

    from controller.core.workspace import Workspace

    rng = np.random.default_rng(seed)
    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    (x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi) = ws.box()
    for x in (x_lo, x_hi):
        for y in (y_lo, y_hi):
            if not ws.contains_xy(x, y):
                raise BenchError("the workspace is not its bounding box (not a rectangle)")
    return np.column_stack(
        [rng.uniform(x_lo, x_hi, n), rng.uniform(y_lo, y_hi, n), rng.uniform(z_lo, z_hi, n)]
    )


def _workspace_centre(cfg: Any) -> tuple[float, float, float]:
    """The anchors' plan-view centroid, half-way up the workspace."""
    from controller.core.workspace import Workspace

    a = cfg.geometry.anchors_m
    _, _, (z_lo, z_hi) = Workspace.from_limits(cfg.limits, cfg.geometry).box()
    return (float(a[:, 0].mean()), float(a[:, 1].mean()), 0.5 * (z_lo + z_hi))


def bench_fpk4(repeats: int, n_poses: int) -> dict[str, float]:
    """`kinematics.fpk` (4 cables, noisy lengths) vs scipy least_squares on the same spheres.

    Returns fpk4_us, scipy_over_fpk4, scipy_us and the largest distance between the two
    solutions (metres). Raises BenchError if scipy did not converge.
    """
    import numpy as np
    from scipy.optimize import least_squares

    from controller.core import kinematics as kin
    from controller.service.config import default_config

    cfg = default_config()
    geom = cfg.geometry
    anchors = np.asarray(geom.anchors_m, dtype=np.float64)
    poses = _workspace_poses(cfg, n_poses, SEED)
    rng = np.random.default_rng(SEED + 1)
    lens = kin.ipk(geom, poses) + rng.normal(0.0, LENGTH_NOISE_M, (n_poses, geom.n_cables))
    rows = [[float(v) for v in row] for row in lens]
    x0 = np.array(_workspace_centre(cfg))

    def residuals(p: Any, lengths: Any) -> Any:
        return np.sqrt(((p - anchors) ** 2).sum(axis=1)) - lengths

    def jacobian(p: Any, lengths: Any) -> Any:
        d = p - anchors
        return d / np.sqrt((d * d).sum(axis=1))[:, None]

    fpk = kin.fpk
    worst = 0.0
    for row, ln in zip(rows, lens, strict=True):
        r = least_squares(residuals, x0, jac=jacobian, args=(ln,))
        if not r.success:
            raise BenchError(f"scipy least_squares did not converge: {r.message}")
        worst = max(worst, math.dist(fpk(geom, row).position_m, tuple(r.x)))

    def run_fpk() -> None:
        for row in rows:
            fpk(geom, row)

    def run_scipy() -> None:
        for ln in lens:
            least_squares(residuals, x0, jac=jacobian, args=(ln,))

    def run_scipy_default() -> None:
        for ln in lens:
            least_squares(residuals, x0, args=(ln,))

    t = interleaved([run_fpk, run_scipy, run_scipy_default], repeats)
    return {
        "scipy_default_over_fpk4": t.ratio(2, 0),
        "fpk4_us": t.cpu(0, n_poses) / 1e3,
        "scipy_us": t.cpu(1, n_poses) / 1e3,
        "scipy_over_fpk4": t.ratio(1, 0),
        "fpk4_wall_us": t.wall(0, n_poses) / 1e3,
        "scipy_wall_us": t.wall(1, n_poses) / 1e3,
        "fpk4_vs_scipy_m": worst,
    }


def bench_batch(repeats: int, n_poses: int) -> dict[str, float]:
    """`kinematics.fpk_batch` over `np.copy` of its input: noisy and consistent lengths."""
    import numpy as np

    from controller.core import kinematics as kin
    from controller.service.config import default_config

    cfg = default_config()
    geom = cfg.geometry
    poses = _workspace_poses(cfg, n_poses, SEED + 2)
    exact = kin.ipk(geom, poses)
    rng = np.random.default_rng(SEED + 3)
    noisy = exact + rng.normal(0.0, LENGTH_NOISE_M, exact.shape)
    out: dict[str, float] = {}
    for name, lens in (("batch_over_copy", noisy), ("batch_over_copy_consistent", exact)):
        res = kin.fpk_batch(geom, lens)
        if not bool(res.valid.all()):
            raise BenchError(f"fpk_batch marked {int((~res.valid).sum())} workspace rows invalid")
        del res  # that run was the batch's warm-up
        np.copy(lens)

        def run_copy(lens: Any = lens) -> None:
            np.copy(lens)

        def run_batch(lens: Any = lens) -> None:
            kin.fpk_batch(geom, lens)

        t = interleaved([run_copy, run_batch], repeats, warm_up=False)
        out[name] = t.ratio(1, 0)
        out[name + "_s"] = t.cpu(1) / 1e9
        out[name + "_copy_s"] = t.cpu(0) / 1e9
        out[name + "_wall_s"] = t.wall(1) / 1e9
    return out


def bench_statics(repeats: int, n_poses: int, batch_poses: int) -> dict[str, float]:
    """Cable tensions for the built-in robot's payload: one pose (solve, and the loop's check)
    and a batch, in microseconds per pose."""
    from controller.core.statics import CableStatics, TensionCheck
    from controller.service.config import default_config

    cfg = default_config()
    assert cfg.payload is not None and cfg.tension is not None
    mass = cfg.payload.mass_kg
    ten = cfg.tension
    statics = CableStatics(cfg.anchors_m, ten.min_n, ten.max_n)
    check = TensionCheck(cfg.anchors_m, mass, ten.min_n, ten.max_n, ten.margin_n)
    poses = [tuple(p) for p in _workspace_poses(cfg, n_poses, SEED + 5).tolist()]
    batch = _workspace_poses(cfg, batch_poses, SEED + 6)
    solve = statics.solve
    checked = check.check

    def run_solve() -> None:
        for p in poses:
            solve(p, mass)

    def run_check() -> None:
        for p in poses:
            checked(p)

    def run_batch() -> None:
        statics.solve_batch(batch, mass)

    t = interleaved([run_solve, run_check], repeats)
    b = interleaved([run_batch], max(3, repeats // 5))
    return {
        "statics_us": t.cpu(0, n_poses) / 1e3,
        "statics_wall_us": t.wall(0, n_poses) / 1e3,
        "statics_check_us": t.cpu(1, n_poses) / 1e3,
        "statics_batch_us": b.cpu(0, batch_poses) / 1e3,
        "statics_batch_wall_us": b.wall(0, batch_poses) / 1e3,
    }


def bench_sim_plant(seconds: float) -> dict[str, float]:
    """Real-time factor of four simulated ODrives carrying the built-in robot's payload at
    1 kHz (module docstring), holding in position control and pulling in torque control."""
    from controller.service.config import default_config, tension_check
    from controller.service.simulated import initial_turns, sim_plant
    from drivers.odrive import cansimple as cs
    from drivers.odrive.sim import SimODriveAxis, step_axes

    cfg = replace(default_config(), sim=replace(default_config().sim, plant="physical"))
    assert cfg.payload is not None and cfg.tension is not None
    assert cfg.homing.power_up_position_m is not None
    turns = initial_turns(cfg)
    pose = tuple(float(v) for v in cfg.homing.power_up_position_m)
    tensions = tension_check(cfg.payload, cfg.tension, cfg.geometry).solve(pose).tensions_n
    dt = 0.001
    ticks = max(1, round(seconds / dt))
    out: dict[str, float] = {}
    for mode in ("position", "torque"):
        plant = sim_plant(cfg, turns)
        axes = [
            SimODriveAxis(n, initial_position_rev=t)
            for n, t in zip(cfg.node_ids, turns, strict=True)
        ]
        for a, r, t, n in zip(axes, cfg.reels, turns, tensions, strict=True):
            a.coupled = True
            if mode == "torque":
                a.handle(cs.SetInputTorque(a.node_id, r.reel.torque_nm(t, n)))
                a.handle(cs.SetControllerMode(a.node_id, cs.ControlMode.TORQUE_CONTROL, 1))
            a.handle(cs.SetAxisState(a.node_id, cs.AxisState.CLOSED_LOOP_CONTROL))

        def run(axes: list[SimODriveAxis] = axes, plant: Any = plant) -> None:
            for _ in range(ticks):
                step_axes(axes, plant, dt)
                for a in axes:
                    a.broadcasts(dt)

        timed = interleaved([run], 1, warm_up=False)
        out[mode] = ticks * dt / (timed.cpu(0) / 1e9)
        out[f"{mode}_tick_us"] = timed.cpu(0, ticks) / 1e3
    return out


def bench_decode(repeats: int, frames: int) -> dict[str, float]:
    """Frames per second through the driver's full receive path (`controller.cli.bench_rx`)."""
    from controller.cli.bench_rx import poll_rate

    poll_rate(min(frames, 5000))  # warm-up
    rates = [poll_rate(frames) for _ in range(repeats)]
    return {"decode_frames_per_s": _median(rates)}
