"""The cost of cable stretch per control tick, for the benchmark (`cablebot bench`).

`stretch_cost_us(cfg)` times, in one run, what the loop calls with rigid cables and with
stretching ones, on the config's robot (default: the paper robot with every cable at EA
2e5 N and its 5 kg payload) along a short path of poses 1 mm apart: the set-point's lengths
(IPK, with the statics solve that plans its tensions) and the pose (FPK, warm-started from the
last pose as the loop does; at rest and moving; with measured tensions). Microseconds per call,
best of `repeats` runs of `calls` calls each.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

__all__ = ["stretch_cost_us"]


def _best_us(fn: Callable[[int], object], calls: int, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        for i in range(calls):
            fn(i)
        best = min(best, time.perf_counter() - t0)
    return best / calls * 1e6


def stretch_cost_us(cfg: Any | None = None, calls: int = 500, repeats: int = 5) -> dict[str, float]:
    """Microseconds per call of the loop's IPK and FPK with rigid and stretching cables.

    Keys: ``ipk_rigid`` (``kinematics.ipk_point``), ``ipk_stretch`` (IPK, statics solve and
    paid-out lengths), ``ipk_stretch_derivative`` (the same with the tension derivative, which
    the loop's plan asks for every 5 cm and hands to the FPK), ``fpk_rigid``
    (``kinematics.fpk``), ``fpk_stretch_rest`` (the last pose is the answer),
    ``fpk_stretch_moving`` (the pose moved 1 mm since the last call), ``fpk_stretch_fast``
    (8 mm: 2 m/s at 250 Hz), each handed the set-point 2 mm ahead, its planned tensions and
    the plan's derivative as the loop does; ``fpk_stretch_no_setpoint`` (8 mm, nothing cached
    and no set-point, as while disarmed: a statics solve and its derivative in the FPK),
    ``fpk_stretch_measured`` (measured tensions), plus ``statics`` (one tension solve) for
    scale. `cfg` is a `RobotConfig` with `[payload]` (default the built-in robot, its cables
    at EA 2e5 N). Raises ValueError for a config without `[payload]`.
    """
    from controller.core import kinematics
    from controller.service.cables import CableModel
    from controller.service.config import default_config, tension_check

    if cfg is None:
        cfg = default_config()
        cfg = replace(cfg, reels=tuple(replace(r, cable_ea_n=2e5) for r in cfg.reels))
    if cfg.payload is None or cfg.tension is None:
        raise ValueError("the stretch benchmark needs a config with [payload]")
    check = tension_check(cfg.payload, cfg.tension, cfg.geometry)
    model = CableModel.from_config(cfg, check)
    if model.stretch is None:
        rigid_reels = tuple(replace(r, cable_ea_n=2e5) for r in cfg.reels)
        model = CableModel.from_config(replace(cfg, reels=rigid_reels), check)
    stretch = model.stretch
    assert stretch is not None
    geom = cfg.geometry
    pu = cfg.homing.power_up_position_m or (0.0, 0.0, 1.0)
    # Two paths along x, points 1 mm and 8 mm apart (8 mm: 2 m/s at 250 Hz); the loop's
    # set-point leads the measured pose by `lead` (the drives' lag): 2 mm.
    lead = 0.002

    def along(step_m: float) -> list[tuple[float, float, float]]:
        return [(float(pu[0]) + step_m * k, float(pu[1]), float(pu[2])) for k in range(calls + 1)]

    def ahead(
        p: tuple[float, float, float],
    ) -> tuple[tuple[float, float, float], tuple[float, ...]]:
        s = (p[0] + lead, p[1], p[2])
        return s, check.solve(s).tensions_n

    path, path8 = along(0.001), along(0.008)
    geo = [kinematics.ipk_point(geom, p) for p in path]
    planned = [check.solve(p).tensions_n for p in path]
    paid = [stretch.paid_out_m(g, t) for g, t in zip(geo, planned, strict=True)]
    paid8 = [stretch.ipk(p)[0] for p in path8]
    at_rest = list(zip(path, planned, strict=True))
    sp1 = [ahead(p) for p in path]
    sp8 = [ahead(p) for p in path8]
    # The derivatives the loop's plan hands over every 5 cm (their solve is the IPK's cost).
    d1 = [check.solve(s, derivative=True).derivative for s, _ in sp1]
    d8 = [check.solve(s, derivative=True).derivative for s, _ in sp8]

    def as_loop(
        paid_m: tuple[float, ...],
        last: tuple[float, float, float],
        sp: tuple[tuple[float, float, float], tuple[float, ...]],
        d: Any,
    ) -> object:
        assert stretch is not None
        if stretch.wants_derivative(sp[0]):
            stretch.take_derivative(sp[0], d)
        return stretch.fpk(paid_m, last, sp)

    def ipk(p: tuple[float, float, float], derivative: bool) -> object:
        return model.commanded_lengths_m(
            kinematics.ipk_point(geom, p), check.solve(p, derivative).tensions_n
        )

    def no_setpoint(i: int) -> object:
        assert stretch is not None
        stretch.reset()
        return stretch.fpk(paid8[i + 1], path8[i])

    out = {
        "ipk_rigid": _best_us(lambda i: kinematics.ipk_point(geom, path[i]), calls, repeats),
        "statics": _best_us(lambda i: check.solve(path[i]), calls, repeats),
        "ipk_stretch": _best_us(lambda i: ipk(path[i], False), calls, repeats),
        "ipk_stretch_derivative": _best_us(lambda i: ipk(path[i], True), calls, repeats),
        "fpk_rigid": _best_us(lambda i: kinematics.fpk(geom, geo[i]), calls, repeats),
        "fpk_stretch_rest": _best_us(
            lambda i: as_loop(paid[i], path[i], at_rest[i], d1[i]), calls, repeats
        ),
        "fpk_stretch_moving": _best_us(
            lambda i: as_loop(paid[i + 1], path[i], sp1[i + 1], d1[i + 1]), calls, repeats
        ),
        "fpk_stretch_fast": _best_us(
            lambda i: as_loop(paid8[i + 1], path8[i], sp8[i + 1], d8[i + 1]), calls, repeats
        ),
        "fpk_stretch_no_setpoint": _best_us(no_setpoint, calls, repeats),
        "fpk_stretch_measured": _best_us(
            lambda i: stretch.fpk_measured(paid[i], planned[i]), calls, repeats
        ),
    }
    return out
