"""The cable-stretch section: the loop's IPK and FPK per call with rigid and with stretching
cables (`controller.cli.stretch_bench.stretch_cost_us`), on the built-in robot's four cables.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from controller.cli.bench.settings import STRETCH_KEYS, TARGET_STRETCH_US, BenchError, Plan
from controller.cli.bench.table import Row

_WHAT = {
    "ipk_rigid": "IPK, rigid cables",
    "ipk_stretch": "IPK + tension solve + paid-out lengths",
    "ipk_stretch_derivative": "the same + the tension derivative (every 5 cm)",
    "fpk_rigid": "FPK, rigid cables",
    "fpk_stretch_rest": "FPK with stretch, at rest",
    "fpk_stretch_moving": "FPK with stretch, moved 1 mm, the set-point's plan",
    "fpk_stretch_fast": "FPK with stretch, moved 8 mm, the set-point's plan",
    "fpk_stretch_no_setpoint": "FPK with stretch, 8 mm, no set-point: statics solved",
    "fpk_stretch_measured": "FPK with stretch, measured tensions",
    "statics": "one tension solve, for scale",
}


def bench_stretch(repeats: int) -> dict[str, float]:
    """Microseconds per call of the loop's IPK and FPK, rigid and with stretch (the keys of
    `STRETCH_KEYS`), best of `repeats` runs of 500 calls each (`stretch_cost_us` on the built-in
    robot with its cables at EA 2e5 N). Raises BenchError if a figure is missing or not finite
    and positive."""
    from controller.cli.stretch_bench import stretch_cost_us

    got = stretch_cost_us(None, repeats=max(1, repeats))
    out: dict[str, float] = {}
    for key in STRETCH_KEYS:
        v = got.get(key)
        if v is None or not (math.isfinite(v) and v > 0.0):
            raise BenchError(f"cable stretch: {key} is {v!r}")
        out[key] = float(v)
    return out


def measure_stretch(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """The cable-stretch section's JSON figures and table rows: a target on every call with
    stretch that the armed loop makes (IPK and FPK). Raises BenchError."""
    log("cable stretch (IPK and FPK, rigid and elastic) ...")
    f = bench_stretch(p.stretch_repeats)
    rep = f"best of {p.stretch_repeats} x 500 calls"
    rows = []
    for key in STRETCH_KEYS:
        # The target is the armed loop's: without a set-point (disarmed) the FPK solves the
        # statics itself, reported for scale.
        with_stretch = "stretch" in key and key != "fpk_stretch_no_setpoint"
        rows.append(
            Row(
                f"stretch_us.{key}",
                f[key],
                "us",
                f"< {TARGET_STRETCH_US:g}" if with_stretch else "",
                f[key] < TARGET_STRETCH_US if with_stretch else None,
                f"{rep}; {_WHAT[key]}",
            )
        )
    return f, rows
