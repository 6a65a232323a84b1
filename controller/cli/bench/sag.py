"""The cable-sag section: the loop's IPK and FPK per call with heavy cables
(`controller.cli.sag_bench.sag_cost_us`), on the built-in robot's four cables as 3 mm steel
rope."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from controller.cli.bench.settings import SAG_KEYS, TARGET_STRETCH_US, BenchError, Plan
from controller.cli.bench.table import Row

_WHAT = {
    "ipk_sag": "IPK with sag: a tick's plan (linearised) + paid-out lengths",
    "ipk_sag_base": "the full solve + its gradients a move makes every 2.5 cm",
    "fpk_sag_rest": "FPK with sag, at rest, the set-point's plan",
    "fpk_sag_moving": "FPK with sag, moved 1 mm, the set-point's plan",
    "fpk_sag_fast": "FPK with sag, moved 8 mm, the set-point's plan",
    "fpk_sag_no_setpoint": "FPK with sag, 8 mm, no set-point: a full solve of its own",
    "sag_solve": "one full solve of the statics with sag, for scale",
}
_TARGETED = ("ipk_sag", "fpk_sag_rest", "fpk_sag_moving", "fpk_sag_fast")
"""The calls the armed loop makes every tick (the full solve comes once per centimetre)."""


def bench_sag(repeats: int) -> dict[str, float]:
    """Microseconds per call of the loop's IPK and FPK with heavy cables (the keys of
    `SAG_KEYS`), best of `repeats` runs (`sag_cost_us` on the built-in robot with 3 mm steel).
    Raises BenchError if a figure is missing or not finite and positive."""
    from controller.cli.sag_bench import sag_cost_us

    got = sag_cost_us(None, repeats=max(1, repeats))
    out: dict[str, float] = {}
    for key in SAG_KEYS:
        v = got.get(key)
        if v is None or not (math.isfinite(v) and v > 0.0):
            raise BenchError(f"cable sag: {key} is {v!r}")
        out[key] = float(v)
    return out


def measure_sag(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """The cable-sag section's JSON figures and table rows: a target on every call with sag
    that the armed loop makes each tick. Raises BenchError."""
    log("cable sag (IPK and FPK with heavy cables) ...")
    f = bench_sag(p.stretch_repeats)
    rep = f"best of {p.stretch_repeats} runs"
    rows = []
    for key in SAG_KEYS:
        targeted = key in _TARGETED
        rows.append(
            Row(
                f"sag_us.{key}",
                f[key],
                "us",
                f"< {TARGET_STRETCH_US:g}" if targeted else "",
                f[key] < TARGET_STRETCH_US if targeted else None,
                f"{rep}; {_WHAT[key]}",
            )
        )
    return f, rows
