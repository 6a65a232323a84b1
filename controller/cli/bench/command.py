"""`cablebot bench`: run the sections, print the table, write the JSON."""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from controller.cli.bench.measure import measure
from controller.cli.bench.settings import (
    CIA402_RATE_HZ,
    FULL,
    FULL_ONLY_SECTIONS,
    QUICK,
    SECTIONS,
    BenchError,
)
from controller.cli.bench.table import format_table, machine_line


def cmd_bench(args: argparse.Namespace) -> int:
    """Entry point of `cablebot bench`."""
    base = QUICK if args.quick else FULL
    plan = replace(
        base,
        batch_poses=args.batch_poses if args.batch_poses is not None else base.batch_poses,
        loop_seconds=args.loop_seconds if args.loop_seconds is not None else base.loop_seconds,
    )

    t_start = time.monotonic()

    def log(msg: str) -> None:
        print(f"[{time.monotonic() - t_start:6.1f} s] {msg}", file=sys.stderr, flush=True)

    default = SECTIONS if args.quick else (*SECTIONS, *FULL_ONLY_SECTIONS)
    sections = tuple(args.only) if args.only else default
    log(f"cablebot bench ({'quick' if args.quick else 'full'}) on {machine_line()}")
    try:
        result, rows, extra = measure(plan, log, sections)
    except BenchError as exc:
        print(f"bench failed: {exc}", file=sys.stderr)
        return 1
    print(f"cablebot bench on {machine_line()}")
    print(format_table(rows))
    for rate, lp in extra.get("loops", {}).items():
        sim = lp["sim_scheduling"]
        print(f"loop {rate} Hz: loop thread {lp['scheduling']}; simulated nodes {sim}")
    if "cia402" in extra:
        ci = extra["cia402"]
        print(
            f"loop {CIA402_RATE_HZ} Hz on CiA 402 drives: loop thread {ci['scheduling']}; "
            f"simulated drives {ci['sim_scheduling']}"
        )
    if "estop" in extra:
        print(f"e-stop under flood: loop thread {extra['estop']['scheduling']}")
    missed = [r.name for r in rows if r.ok is False]
    print("MISSED: " + ", ".join(missed) if missed else "all targets met")
    if args.json is not None:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot bench`."""
    p = sub.add_parser(
        "bench",
        help="measure FPK, receive path, loop timing and latency on this machine",
        description="Measure where the time goes on this machine and compare with the targets.",
    )
    p.add_argument("--quick", action="store_true", help="fewer repeats, 2 s loop runs")
    p.add_argument("--json", type=Path, default=None, metavar="FILE", help="write the figures")
    p.add_argument(
        "--only",
        nargs="+",
        choices=(*SECTIONS, *FULL_ONLY_SECTIONS),
        default=None,
        metavar="SECTION",
        help=(
            f"run only these sections ({', '.join((*SECTIONS, *FULL_ONLY_SECTIONS))}); the JSON"
            " has their keys only"
        ),
    )
    # For the test: smaller batch and shorter loop runs.
    p.add_argument("--batch-poses", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument("--loop-seconds", type=float, default=None, help=argparse.SUPPRESS)
    p.set_defaults(func=cmd_bench)
