"""The benchmark's table: one row per figure with its target and PASS/MISSED."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True, slots=True)
class Row:
    """One line of the table."""

    name: str
    value: float | int
    unit: str
    target: str
    ok: bool | None
    repeats: str


def _fmt_value(v: float | int, unit: str) -> str:
    if isinstance(v, int):
        return f"{v:,}"
    if unit == "frac":
        return f"{v:.4f}"
    if abs(v) >= 1e4:
        return f"{v:,.0f}"
    if abs(v) >= 100:
        return f"{v:.1f}"
    if abs(v) >= 1:
        return f"{v:.3f}"
    return f"{v:.3g}"


def format_table(rows: Sequence[Row]) -> str:
    """The results as an aligned text table; MISSED rows are marked with '<--'."""
    head = ("figure", "value", "unit", "target", "result", "repeats")
    body = [
        (
            r.name,
            _fmt_value(r.value, r.unit),
            r.unit,
            r.target,
            "" if r.ok is None else ("PASS" if r.ok else "MISSED"),
            r.repeats,
        )
        for r in rows
    ]
    widths = [max(len(x[k]) for x in [head, *body]) for k in range(len(head))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    for r, cells in zip(rows, body, strict=True):
        line = "  ".join(c.ljust(w) for c, w in zip(cells, widths, strict=True)).rstrip()
        lines.append(line + ("   <--" if r.ok is False else ""))
    return "\n".join(lines)


def _frames_row(name: str, lp: dict[str, Any]) -> Row:
    """The frames a loop run's driver received per tick (every frame on the bus: udp_multicast
    echoes the loop's own) and, in the detail, those it sent."""
    return Row(
        name,
        lp["frames_rx_per_tick"],
        "",
        "",
        None,
        f"sent {lp['frames_tx_per_tick']:.2f}/tick; received counts the loop's own",
    )


def machine_line() -> str:
    """CPU model, core count, load and Python version, for the table's header."""
    model = "unknown CPU"
    with contextlib.suppress(OSError), open("/proc/cpuinfo", encoding="utf-8") as f:
        for line in f:
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    load = ""
    with contextlib.suppress(OSError):
        load = " load {:.2f} {:.2f} {:.2f},".format(*os.getloadavg())
    return f"{model}, {os.cpu_count()} cores,{load} Python {sys.version.split()[0]}"
