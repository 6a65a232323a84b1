"""`python -m chaos` (with `tools/` on the path; `make chaos`): the chaos run.

Starts one worker process per drive family (`--families`), each running its own daemon and
equipment for `--duration-s` seconds (default 600), then prints the faults injected per kind,
their outcomes (rode through / named fault / recovered), the invariant violations, the e-stop
times, the pose sequence and the daemon's memory, and writes the whole report as JSON
(`--json`). Exit status 0 when every worker ran and no invariant broke, 1 otherwise.

`--busy-loops N` runs N busy loops beside the run for its whole length (the measurement of
docs/chaos.md: two of them).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

TOOLS = Path(__file__).resolve().parents[1]
FAMILIES = ("odrive", "cia402")
_W = (8, 6, 5, 6, 6, 6)


def _args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m chaos", description=__doc__.split("\n\n")[0])
    p.add_argument(
        "--duration-s", type=float, default=600.0, help="length of the run (default 600)"
    )
    p.add_argument("--families", default=",".join(FAMILIES), help="drive families, comma-separated")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: from the clock)")
    p.add_argument("--workdir", default=None, help="keep robot files and daemon logs here")
    p.add_argument("--json", default=None, help="write the report here")
    p.add_argument("--busy-loops", type=int, default=0, help="busy loops beside the whole run")
    p.add_argument("--kinds", default="", help="inject only these fault kinds (comma-separated)")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    p.add_argument("--tag", default="0", help=argparse.SUPPRESS)
    return p.parse_args(argv)


def _worker(args: argparse.Namespace) -> int:
    import signal

    from chaos.worker import STOP, run_worker

    def on_signal(signum: int, frame: object) -> None:
        STOP.set()  # the run ends at its next step and undoes what it changed on the host

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    kinds = [k for k in args.kinds.split(",") if k]
    report = run_worker(args.worker, args.duration_s, args.seed, args.workdir, args.tag, kinds)
    Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the chaos run (or, with --worker, one worker)."""
    args = _args(argv)
    if args.worker:
        return _worker(args)
    seed = args.seed if args.seed is not None else int(time.time()) % 100000
    families = [f for f in args.families.split(",") if f]
    bad = [f for f in families if f not in FAMILIES]
    if bad:
        print(f"chaos: unknown drive family {bad}: choose from {list(FAMILIES)}", file=sys.stderr)
        return 2
    work = Path(args.workdir) if args.workdir else Path(tempfile.mkdtemp(prefix="cbchaos-"))
    work.mkdir(parents=True, exist_ok=True)
    print(
        f"chaos: {args.duration_s:.0f} s, families {families}, seed {seed}, work in {work}",
        flush=True,
    )
    env = dict(os.environ, PYTHONPATH=f"{TOOLS}{os.pathsep}{TOOLS.parent}")
    from chaos.robot import busy_loops, die_with_parent

    hogs = busy_loops(args.busy_loops)
    procs: dict[str, tuple[subprocess.Popen[bytes], Path]] = {}
    rng = random.Random(seed)

    def forward(signum: int, frame: object) -> None:
        for p, _ in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)  # each worker tears down and reports

    signal.signal(signal.SIGTERM, forward)
    signal.signal(signal.SIGINT, forward)
    try:
        for i, fam in enumerate(families):
            out = work / f"{fam}.json"
            out.unlink(missing_ok=True)
            cmd = [
                sys.executable, "-m", "chaos", "--worker", fam,
                "--duration-s", str(args.duration_s), "--seed", str(rng.randrange(1 << 30)),
                "--workdir", str(work / fam), "--json", str(out),
                "--tag", f"{os.getpid() % 10000}{i}", "--kinds", args.kinds,
            ]  # fmt: skip
            procs[fam] = (
                subprocess.Popen(
                    cmd,
                    env=env,
                    cwd=TOOLS.parent,
                    preexec_fn=lambda: die_with_parent(signal.SIGTERM),
                ),
                out,
            )
        deadline = time.monotonic() + args.duration_s + 300.0
        for p, _ in procs.values():
            p.wait(max(1.0, deadline - time.monotonic()))
    finally:
        for p, _ in procs.values():
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(60)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(10)
        for h in hogs:
            h.kill()
            h.wait(10)
    reports: list[dict[str, Any]] = []
    failed: list[str] = []
    for fam, (p, out) in procs.items():
        if p.returncode != 0 or not out.exists():
            failed.append(f"{fam}: worker exit status {p.returncode}")
            continue
        reports.append(json.loads(out.read_text()))
    summary = {
        "seed": seed,
        "duration_s": args.duration_s,
        "busy_loops": args.busy_loops,
        "workers": reports,
        "failed": failed,
    }
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=1))
    print(render(summary))
    ok = not failed and all(not r["violations"] for r in reports)
    return 0 if ok else 1


def render(summary: dict[str, Any]) -> str:
    """The report as a person reads it."""
    lines = []
    for r in summary["workers"]:
        lines.append(
            f"\n{r['family']}: {r['elapsed_s']} s, seed {r['seed']},"
            f" daemon started {r['daemon_starts']}x"
        )
        heads = ("injected", "armed", "rode", "named", "recov", "rehome")
        lines.append(
            f"  {'fault':<20} " + " ".join(f"{h:>{w}}" for h, w in zip(heads, _W, strict=True))
        )
        tot = [0] * 6
        for kind, k in sorted(r["faults"].items()):
            row = [
                k["injected"],
                k["while_armed"],
                k["rode_through"],
                k["named_fault"],
                k["recovered"],
                k["rehomed"],
            ]
            tot = [a + b for a, b in zip(tot, row, strict=True)]
            lines.append(
                f"  {kind:<20} " + " ".join(f"{v:>{w}}" for v, w in zip(row, _W, strict=True))
            )
        lines.append(
            f"  {'total':<20} " + " ".join(f"{v:>{w}}" for v, w in zip(tot, _W, strict=True))
        )
        for kind, why in r["unavailable"].items():
            lines.append(f"  not injected: {kind}: {why}")
        rss = r["rss"]
        lines.append(
            f"  poses {r['poses']}, sequence lost {r['pose_seq_lost']}"
            f" (+{r['pose_seq_lost_in_stalls']} in stalls; the daemon overwrote"
            f" {r['pose_overwritten']}); RSS {rss.get('start_mib')} (settled"
            f" {rss.get('settled_mib')}) -> {rss.get('end_mib')} MiB over {rss.get('span_s')} s,"
            f" slope {rss.get('slope_mib_per_min')} MiB/min (second half"
            f" {rss.get('second_half_slope_mib_per_min')})"
        )
        lines.append(
            f"  e-stop: every drive's frame on the bus after the request {r['estop_frames_ms']} ms"
            f" ({r['estop_over_target']} over the 50 ms target); drives out of closed loop"
            f" {r['estop_drives_out_ms']} ms"
        )
        if r["unprovoked"]:
            n = len(r["unprovoked"])
            ok = all(u["recovery"]["ok"] for u in r["unprovoked"])
            reasons = sorted({str(u["reason"]).split(":")[0] for u in r["unprovoked"]})
            lines.append(
                f"  unprovoked faults (stalls of the machine): {n}"
                f" ({', '.join(reasons)}){', all recovered' if ok else ''}"
            )
        lines.append(f"  client: {r['flights']}; link {r['link']}; tap {r['tap']}")
        st = r["machine_stalls"]
        lines.append(
            f"  machine stalls seen (100 ms or more): {st['count']}, longest {st['longest_s']} s"
        )
        for e in r["excused"]:
            stall = f"{e['machine_stall_s']} s" if e["machine_stall_s"] else "machine stall"
            lines.append(f"  excused (a {stall}): {e['kind']}: {e['what']}")
        lines.append(f"  invariant violations: {len(r['violations'])}")
        lines.extend(
            f"    {v['t_s']:>7.1f} s  {v['kind']}: {v['text']}" for v in r["violations"][:40]
        )
    for f in summary["failed"]:
        lines.append(f"FAILED {f}")
    n = sum(len(r["violations"]) for r in summary["workers"])
    verdict = "PASS" if not summary["failed"] and n == 0 else "FAIL"
    lines.append(
        f"\nchaos: {verdict}: {n} invariant violations, {len(summary['failed'])} workers failed"
    )
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
