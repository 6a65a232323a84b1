"""The cost of cable sag per control tick, for the benchmark (`cablebot bench`).

`sag_cost_us(cfg)` times, in one run, what the loop calls with heavy cables on the config's
robot (default: the built-in paper robot with 3 mm steel rope on every reel, EA 4.5e5 N and
0.036 kg/m, carrying its 5 kg payload) along a path of set-points: the set-point's plan and
paid-out lengths (IPK: the tension rule's solve, linearised from the last full solve within
2.5 cm, as every tick of a move makes it), the full solve with its gradients that a move makes
every 2.5 cm, and the pose (FPK, warm-started from the last pose and handed the set-point's plan
as the loop does; at rest, moved 1 mm and 8 mm; and without a set-point, as while disarmed).
Microseconds of the thread's CPU time per call (the machine's load does not count: the loop
thread's own cost), best of `repeats` runs of `calls` calls each.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

__all__ = ["STEEL_EA_N", "STEEL_KG_PER_M", "sag_config", "sag_cost_us"]

STEEL_EA_N = 4.5e5
"""EA of the benchmark's cables (N)."""
STEEL_KG_PER_M = 0.036
"""Mass per metre of the benchmark's cables: 3 mm steel rope (kg/m)."""


def sag_config(cfg: Any | None = None) -> Any:
    """`cfg` (default: the built-in robot) with every reel's cable 3 mm steel rope. Raises
    nothing."""
    from controller.service.config import default_config

    base = default_config() if cfg is None else cfg
    reels = tuple(
        replace(r, cable_ea_n=STEEL_EA_N, cable_mass_kg_per_m=STEEL_KG_PER_M) for r in base.reels
    )
    return replace(base, reels=reels)


def _best_us(fn: Callable[[int], object], calls: int, repeats: int, reset: Any = None) -> float:
    best = float("inf")
    for _ in range(repeats):
        if reset is not None:
            reset()
        t0 = time.thread_time()
        for i in range(calls):
            fn(i)
        best = min(best, time.thread_time() - t0)
    return best / calls * 1e6


def sag_cost_us(cfg: Any | None = None, calls: int = 500, repeats: int = 5) -> dict[str, float]:
    """Microseconds per call of the loop's IPK and FPK with heavy cables.

    Keys: ``ipk_sag`` (a tick of a move at 2 m/s and 250 Hz, 8 mm: the plan linearised from the
    last full solve and the paid-out lengths), ``ipk_sag_base`` (a tick that makes a new base:
    the full solve, started from the last, with the gradients of the horizontal forces and of
    the paid-out lengths, every 2.5 cm of a move), ``fpk_sag_rest`` (the last pose
    is the answer), ``fpk_sag_moving`` (moved 1 mm), ``fpk_sag_fast`` (8 mm: 2 m/s at 250 Hz),
    each handed the set-point 2 mm ahead and its plan as the loop does;
    ``fpk_sag_no_setpoint`` (8 mm, no plan near: the FPK plans, as while disarmed), and
    ``sag_solve`` (one full solve, for scale).  `cfg` is a `RobotConfig` with `[payload]`
    (default the built-in robot with 3 mm steel, `sag_config`).  Raises ValueError for a
    config without `[payload]` or heavy cables.
    """
    from controller.core import kinematics
    from controller.service.cables import CableModel
    from controller.service.config import tension_check

    cfg = sag_config() if cfg is None else cfg
    if cfg.payload is None or cfg.tension is None:
        raise ValueError("the sag benchmark needs a config with [payload]")
    check: Any = tension_check(cfg.payload, cfg.tension, cfg.geometry, cfg.reels)
    model = CableModel.from_config(cfg, check)
    planner = model.sag
    if planner is None:
        raise ValueError("the sag benchmark needs heavy cables (reels' cable_mass_kg_per_m)")
    geom = cfg.geometry
    pu = cfg.homing.power_up_position_m or (0.0, 0.0, 1.0)
    lead = 0.002  # the set-point leads the measured pose by the drives' lag

    def along(step_m: float) -> list[tuple[float, float, float]]:
        return [(float(pu[0]) + step_m * k, float(pu[1]), float(pu[2])) for k in range(calls + 1)]

    path, path8 = along(0.001), along(0.008)
    # the paid-out lengths of each pose (the truth the FPK must find), from full solves
    paid = [check.sag.solve(p).paid_out_m for p in path]
    paid8 = [check.sag.solve(p).paid_out_m for p in path8]

    def ipk_calls(seq: list[tuple[float, float, float]]) -> tuple[float, float]:
        """(us per tick that linearises, us per tick that makes a new base): the loop's plan
        of each set-point and its paid-out lengths, along `seq`, best of `repeats` runs."""
        best_lin = best_base = float("inf")
        lengths = [kinematics.ipk_point(geom, p) for p in seq]
        for _ in range(repeats):
            planner.reset()
            check.solve(seq[0])
            t_lin = t_base = 0.0
            n_lin = n_base = 0
            for p, ch in zip(seq[1:], lengths[1:], strict=True):
                t0 = time.thread_time()
                check.solve(p)
                model.commanded_lengths_m(ch, None)
                dt = time.thread_time() - t0
                if planner.planned(position_m=p).iterations > 0:  # type: ignore[union-attr]
                    t_base += dt
                    n_base += 1
                else:
                    t_lin += dt
                    n_lin += 1
            best_lin = min(best_lin, t_lin / max(1, n_lin))
            best_base = min(best_base, t_base / max(1, n_base))
        return best_lin * 1e6, best_base * 1e6

    def timed_fpk(
        seq: list[tuple[float, float, float]], lengths: list[tuple[float, ...]], step: int
    ) -> float:
        """The FPK alone, as the loop calls it: each call after the plan of its set-point
        (2 mm ahead of the pose; not timed), handed that plan."""
        best = float("inf")
        for _ in range(repeats):
            planner.reset()
            total = 0.0
            for i in range(calls):
                q = seq[i + step]
                sp = (q[0] + lead, q[1], q[2])
                check.solve(sp)
                t0 = time.thread_time()
                planner.fpk(lengths[i + step], seq[i], sp)
                total += time.thread_time() - t0
            best = min(best, total)
        return best / calls * 1e6

    def no_setpoint(i: int) -> object:
        planner.reset()
        return planner.fpk(paid8[i + 1], path8[i])

    ipk_lin, ipk_base = ipk_calls(path8)
    return {
        "ipk_sag": ipk_lin,
        "ipk_sag_base": ipk_base,
        "fpk_sag_rest": timed_fpk(path, paid, 0),
        "fpk_sag_moving": timed_fpk(path, paid, 1),
        "fpk_sag_fast": timed_fpk(path8, paid8, 1),
        "fpk_sag_no_setpoint": _best_us(no_setpoint, calls // 10 or 1, repeats),
        "sag_solve": _best_us(lambda i: check.sag.solve(path[i]), calls // 10 or 1, repeats),
    }
