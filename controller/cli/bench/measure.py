"""Each section of the benchmark measured and turned into its JSON figures and table rows."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from controller.cli.bench.compute import measure_compute
from controller.cli.bench.estop import bench_estop_flood
from controller.cli.bench.figures import (
    bench_batch,
    bench_decode,
    bench_fpk4,
    bench_sim_plant,
    bench_statics,
    bench_three_spheres,
)
from controller.cli.bench.layouts import measure_layouts
from controller.cli.bench.loop import bench_loop, merge_runs
from controller.cli.bench.planning import measure_planning
from controller.cli.bench.ros2 import measure_ros2
from controller.cli.bench.sag import measure_sag
from controller.cli.bench.settings import (
    CIA402_RATE_HZ,
    E2E_MARGIN_US,
    E2E_RATE_HZ,
    ESTOP_FLOOD_THREADS,
    ESTOP_KEYS,
    FULL_ONLY_JSON_KEYS,
    FULL_ONLY_SECTIONS,
    JSON_KEYS,
    LOOP_KEYS,
    LOOP_RATES_HZ,
    SECTIONS,
    TARGET_BATCH_OVER_COPY,
    TARGET_COMPUTE_P99_FRAC,
    TARGET_DECODE_FRAMES_PER_S,
    TARGET_ESTOP_FLOOD_P99_MS,
    TARGET_JITTER_P99_FRAC,
    TARGET_OVERRUN_FRAC,
    TARGET_SCIPY_OVER_FPK4,
    TARGET_SIM_RTF,
    TARGET_SIMPLIFIED_OVER_GENERAL,
    TARGET_SIMPLIFIED_US,
    Plan,
)
from controller.cli.bench.shaping import measure_shaping
from controller.cli.bench.stretch import measure_stretch
from controller.cli.bench.table import Row, _frames_row


def _measure_kinematics(
    p: Plan, log: Callable[[str], None]
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any], list[Row]]:
    """Measure the scalar three-spheres FPK, `fpk` against scipy and the batch FPK.

    Returns their figures and table rows. Raises BenchError.
    """
    rows: list[Row] = []
    log("three-spheres (scalar) ...")
    ts = bench_three_spheres(p.scalar_repeats, p.scalar_calls)
    rep = f"median of {p.scalar_repeats} x {p.scalar_calls} calls"
    rows += [
        Row(
            "fpk_simplified_us",
            ts["fpk_simplified_us"],
            "us",
            f"< {TARGET_SIMPLIFIED_US:g}",
            ts["fpk_simplified_us"] < TARGET_SIMPLIFIED_US,
            f"{rep}; wall {ts['fpk_simplified_wall_us']:.3g}",
        ),
        Row(
            "fpk_general_us",
            ts["fpk_general_us"],
            "us",
            "",
            None,
            f"{rep}; wall {ts['fpk_general_wall_us']:.3g}",
        ),
        Row(
            "fpk_simplified_over_general",
            ts["fpk_simplified_over_general"],
            "ratio",
            f"<= {TARGET_SIMPLIFIED_OVER_GENERAL:g}",
            ts["fpk_simplified_over_general"] <= TARGET_SIMPLIFIED_OVER_GENERAL,
            f"median of {p.scalar_repeats} interleaved pairs",
        ),
    ]

    log("fpk (4 cables) vs scipy least_squares ...")
    f4 = bench_fpk4(p.fpk4_repeats, p.fpk4_poses)
    rep = f"median of {p.fpk4_repeats} x {p.fpk4_poses} poses"
    rows += [
        Row("fpk4_us", f4["fpk4_us"], "us", "", None, f"{rep}; wall {f4['fpk4_wall_us']:.3g}"),
        Row(
            "  scipy least_squares",
            f4["scipy_us"],
            "us",
            "",
            None,
            f"{rep}; wall {f4['scipy_wall_us']:.4g}",
        ),
        Row(
            "scipy_over_fpk4",
            f4["scipy_over_fpk4"],
            "ratio",
            f">= {TARGET_SCIPY_OVER_FPK4:g}",
            f4["scipy_over_fpk4"] >= TARGET_SCIPY_OVER_FPK4,
            f"median of {p.fpk4_repeats} interleaved pairs",
        ),
        Row(
            "  scipy_over_fpk4 (2-point jac)",
            f4["scipy_default_over_fpk4"],
            "ratio",
            "",
            None,
            "scipy's default Jacobian",
        ),
        Row("  |fpk - scipy| max", f4["fpk4_vs_scipy_m"], "m", "", None, f"{p.fpk4_poses} poses"),
    ]

    log(f"batch fpk on {p.batch_poses:,} poses ...")
    bt = bench_batch(p.batch_repeats, p.batch_poses)
    rep = f"median of {p.batch_repeats} interleaved pairs"
    rows += [
        Row(
            "batch_over_copy",
            bt["batch_over_copy"],
            "ratio",
            f"<= {TARGET_BATCH_OVER_COPY:g}",
            bt["batch_over_copy"] <= TARGET_BATCH_OVER_COPY,
            rep,
        ),
        Row(
            "  batch fpk (noisy)",
            bt["batch_over_copy_s"],
            "s",
            "",
            None,
            f"{rep}; wall {bt['batch_over_copy_wall_s']:.3g}",
        ),
        Row("  np.copy", bt["batch_over_copy_copy_s"], "s", "", None, rep),
        Row(
            "  batch_over_copy (consistent)",
            bt["batch_over_copy_consistent"],
            "ratio",
            "",
            None,
            rep,
        ),
    ]
    return ts, f4, bt, rows


def _measure_statics(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """Measure statics per pose, single and batched: figures and rows. Raises BenchError."""
    rows: list[Row] = []
    log("statics (tensions for the payload) ...")
    sx = bench_statics(p.statics_repeats, p.statics_poses, p.statics_batch_poses)
    rep = f"median of {p.statics_repeats} x {p.statics_poses} poses"
    rows += [
        Row(
            "statics_us",
            sx["statics_us"],
            "us",
            "",
            None,
            f"{rep}; wall {sx['statics_wall_us']:.3g}",
        ),
        Row("  tension check (loop)", sx["statics_check_us"], "us", "", None, rep),
        Row(
            "statics_batch_us",
            sx["statics_batch_us"],
            "us",
            "",
            None,
            f"{p.statics_batch_poses:,} poses per batch; wall {sx['statics_batch_wall_us']:.3g}",
        ),
    ]
    return sx, rows


def _measure_sim(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """Measure the physical simulator's real-time factor: figures and rows."""
    log("physical simulator ...")
    sp = bench_sim_plant(p.sim_seconds)
    rows = [
        Row(
            f"sim_plant_rtf.{mode}",
            sp[mode],
            "x",
            f">= {TARGET_SIM_RTF:g}",
            sp[mode] >= TARGET_SIM_RTF,
            f"{p.sim_seconds:g} simulated s at 1 kHz, 4 axes; "
            f"{sp[mode + '_tick_us']:.3g} us a tick",
        )
        for mode in ("position", "torque")
    ]
    return sp, rows


def _measure_decode(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """Measure the receive path: its figures and table rows. Raises BenchError."""
    rows: list[Row] = []
    log("receive path ...")
    dc = bench_decode(p.decode_repeats, p.decode_frames)
    rows.append(
        Row(
            "decode_frames_per_s",
            dc["decode_frames_per_s"],
            "1/s",
            f">= {TARGET_DECODE_FRAMES_PER_S:,.0f}",
            dc["decode_frames_per_s"] >= TARGET_DECODE_FRAMES_PER_S,
            f"median of {p.decode_repeats} x {p.decode_frames:,} frames",
        ),
    )
    return dc, rows


def _measure_loops(
    p: Plan, log: Callable[[str], None]
) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any], list[Row]]:
    """Measure the daemon's loop at each rate on simulated ODrives, at 500 Hz on simulated
    CiA 402 drives, and the end-to-end latency.

    Returns the merged runs per rate, the CiA 402 runs, the end-to-end rate's runs and the table
    rows. Raises BenchError.
    """
    rows: list[Row] = []
    runs: dict[str, list[dict[str, Any]]] = {str(rate): [] for rate in LOOP_RATES_HZ}
    for k in range(p.loop_runs):
        for rate in LOOP_RATES_HZ:  # rates interleaved, so load drifts hit both alike
            log(f"loop at {rate} Hz for {p.loop_seconds:g} s (run {k + 1}/{p.loop_runs}) ...")
            lp = bench_loop(rate, p.loop_seconds)
            runs[str(rate)].append(lp)
            for reason in lp["fault_reasons"]:
                log(f"  fault at {rate} Hz: {reason}")
    loops = {rate: merge_runs(rs) for rate, rs in runs.items()}
    for rate in LOOP_RATES_HZ:
        lp = loops[str(rate)]
        at_1k = rate == 1000
        n = f"median of {lp['runs']} runs of {lp['seconds']:.1f} s"
        over_frac = lp["overrun_frac"]
        rows += [
            Row(
                f"loop.{rate}.faults",
                lp["faults"],
                "",
                "0",
                lp["faults"] == 0,
                "; ".join(lp["fault_reasons"])[:60],
            ),
            Row(f"loop.{rate}.ticks", lp["ticks"], "", "", None, n),
            Row(
                f"loop.{rate}.overruns",
                lp["overruns"],
                "",
                f"< {TARGET_OVERRUN_FRAC:.1%} of ticks" if at_1k else "",
                over_frac < TARGET_OVERRUN_FRAC if at_1k else None,
                f"{over_frac:.3%} of ticks",
            ),
            Row(f"loop.{rate}.jitter_p50_frac", lp["jitter_p50_frac"], "frac", "", None, n),
            Row(
                f"loop.{rate}.jitter_p99_frac",
                lp["jitter_p99_frac"],
                "frac",
                f"<= {TARGET_JITTER_P99_FRAC:g}" if at_1k else "",
                lp["jitter_p99_frac"] <= TARGET_JITTER_P99_FRAC if at_1k else None,
                n,
            ),
            Row(f"loop.{rate}.compute_p50_frac", lp["compute_p50_frac"], "frac", "", None, n),
            Row(
                f"loop.{rate}.compute_p99_frac",
                lp["compute_p99_frac"],
                "frac",
                f"<= {TARGET_COMPUTE_P99_FRAC:g}" if at_1k else "",
                lp["compute_p99_frac"] <= TARGET_COMPUTE_P99_FRAC if at_1k else None,
                n,
            ),
            _frames_row(f"loop.{rate}.frames_rx_per_tick", lp),
        ]

    cia_runs = []
    for k in range(p.loop_runs):
        log(
            f"loop at {CIA402_RATE_HZ} Hz on simulated CiA 402 drives for {p.loop_seconds:g} s "
            f"(run {k + 1}/{p.loop_runs}) ..."
        )
        lp = bench_loop(CIA402_RATE_HZ, p.loop_seconds, "cia402")
        cia_runs.append(lp)
        for reason in lp["fault_reasons"]:
            log(f"  fault on CiA 402 drives: {reason}")
    ci = merge_runs(cia_runs)
    name = f"loop.cia402.{CIA402_RATE_HZ}"
    n = f"median of {ci['runs']} runs of {ci['seconds']:.1f} s"
    rows += [
        Row(
            f"{name}.faults",
            ci["faults"],
            "",
            "0",
            ci["faults"] == 0,
            "; ".join(ci["fault_reasons"])[:60],
        ),
        Row(f"{name}.ticks", ci["ticks"], "", "", None, n),
        Row(f"{name}.overruns", ci["overruns"], "", "", None, f"{ci['overrun_frac']:.3%} of ticks"),
        Row(f"{name}.jitter_p99_frac", ci["jitter_p99_frac"], "frac", "", None, n),
        Row(f"{name}.compute_p50_frac", ci["compute_p50_frac"], "frac", "", None, n),
        Row(f"{name}.compute_p99_frac", ci["compute_p99_frac"], "frac", "", None, n),
        _frames_row(f"{name}.frames_rx_per_tick", ci),
    ]

    k5 = loops["500"]
    rows.append(
        Row(
            "  e2e_p50_us at 500 Hz",
            k5["e2e_p50_us"],
            "us",
            "",
            None,
            f"median of {k5['runs']} runs; p99 {k5['e2e_p99_us']:.0f}",
        )
    )
    k1 = loops[str(E2E_RATE_HZ)]
    e2e_target = 1e6 / E2E_RATE_HZ + E2E_MARGIN_US
    e2e_n = f"median of {k1['runs']} runs, {k1['e2e_n']} frames"
    rows += [
        Row(
            "zenoh_put_us",
            k1["zenoh_put_us"],
            "us",
            "",
            None,
            f"median of {k1['runs']} runs of {min(k1['zenoh_put_n'], 4096)} loop puts",
        ),
        Row(
            "e2e_p50_us",
            k1["e2e_p50_us"],
            "us",
            f"<= {e2e_target:g}",
            k1["e2e_p50_us"] <= e2e_target,
            e2e_n,
        ),
        Row("e2e_p99_us", k1["e2e_p99_us"], "us", "", None, e2e_n),
        Row(
            "  e2e send -> daemon publish p50",
            k1["send_to_publish_p50_us"],
            "us",
            "",
            None,
            f"p99 {k1['send_to_publish_p99_us']:.0f}",
        ),
        Row(
            "  e2e publish -> subscriber p50",
            k1["publish_to_arrival_p50_us"],
            "us",
            "",
            None,
            f"p99 {k1['publish_to_arrival_p99_us']:.0f}",
        ),
    ]
    return loops, ci, k1, rows


def _measure_estop(p: Plan, log: Callable[[str], None]) -> tuple[dict[str, Any], list[Row]]:
    """Measure e-stop latency under a flood of commands: figures and rows. Raises BenchError."""
    rows: list[Row] = []
    log(f"e-stop under a flood of hostile commands ({p.estop_tries} tries) ...")
    es = bench_estop_flood(p.estop_tries)
    flood = (
        f"{es['tries']} tries; flood {es['flood_per_s']:.0f} queries/s, "
        f"{ESTOP_FLOOD_THREADS} in flight"
    )
    rows += [
        Row(
            "estop_latency_flood_ms.reply_p99",
            es["reply_p99"],
            "ms",
            f"< {TARGET_ESTOP_FLOOD_P99_MS:g}",
            es["reply_p99"] < TARGET_ESTOP_FLOOD_P99_MS,
            f"p50 {es['reply_p50']:.1f}, max {es['reply_max']:.1f}; {flood}",
        ),
        Row(
            "estop_latency_flood_ms.frame_p99",
            es["frame_p99"],
            "ms",
            f"< {TARGET_ESTOP_FLOOD_P99_MS:g}",
            es["frame_p99"] < TARGET_ESTOP_FLOOD_P99_MS,
            f"p50 {es['frame_p50']:.1f}, max {es['frame_max']:.1f}; all axes' Estop frames",
        ),
        Row(
            "  robot faults during the flood",
            es["faults"],
            "",
            "0",
            es["faults"] == 0,
            "; ".join(es["fault_reasons"])[:60],
        ),
    ]
    return es, rows


def measure(
    plan: Plan, log: Callable[[str], None], sections: Sequence[str] = SECTIONS
) -> tuple[dict[str, Any], list[Row], dict[str, Any]]:
    """Run the benchmarks of `sections` (default: all of `SECTIONS`) with `plan`; returns the
    JSON mapping of their figures (all of `JSON_KEYS` when every section runs), the table rows
    and the loop runs' full results (`{"loops": {rate: {...}}, "cia402": ..., "estop": ...}`,
    for the sections that ran).

    Raises BenchError when a figure cannot be measured, ValueError for an unknown section.
    """
    known = (*SECTIONS, *FULL_ONLY_SECTIONS)
    unknown = [s for s in sections if s not in known]
    if unknown:
        raise ValueError(f"unknown bench sections {unknown}; known: {', '.join(known)}")
    rows: list[Row] = []
    result: dict[str, Any] = {}
    extra: dict[str, Any] = {}
    p = plan
    if "kinematics" in sections:
        ts, f4, bt, part = _measure_kinematics(p, log)
        rows += part
        result["fpk_simplified_us"] = ts["fpk_simplified_us"]
        result["fpk_general_us"] = ts["fpk_general_us"]
        result["fpk_simplified_over_general"] = ts["fpk_simplified_over_general"]
        result["fpk4_us"] = f4["fpk4_us"]
        result["scipy_over_fpk4"] = f4["scipy_over_fpk4"]
        result["batch_over_copy"] = bt["batch_over_copy"]
    if "statics" in sections:
        sx, part = _measure_statics(p, log)
        rows += part
        result["statics_us"] = sx["statics_us"]
        result["statics_batch_us"] = sx["statics_batch_us"]
    if "sim" in sections:
        sp, part = _measure_sim(p, log)
        rows += part
        result["sim_plant_rtf"] = {"position": sp["position"], "torque": sp["torque"]}
    if "decode" in sections:
        dc, part = _measure_decode(p, log)
        rows += part
        result["decode_frames_per_s"] = dc["decode_frames_per_s"]
    if "loops" in sections:
        loops, ci, k1, part = _measure_loops(p, log)
        rows += part
        result["zenoh_put_us"] = float(k1["zenoh_put_us"])
        result["loop"] = {
            str(rate): {key: loops[str(rate)][key] for key in LOOP_KEYS} for rate in LOOP_RATES_HZ
        }
        result["e2e_p50_us"] = k1["e2e_p50_us"]
        result["e2e_p99_us"] = k1["e2e_p99_us"]
        extra["loops"] = loops
        extra["cia402"] = ci
    if "estop" in sections:
        es, part = _measure_estop(p, log)
        rows += part
        result["estop_latency_flood_ms"] = {key: es[key] for key in ESTOP_KEYS}
        extra["estop"] = es
    if "planning" in sections:
        result["planning"], part = measure_planning(p, log)
        rows += part
    if "stretch" in sections:
        result["stretch_us"], part = measure_stretch(p, log)
        rows += part
    if "sag" in sections:
        result["sag_us"], part = measure_sag(p, log)
        rows += part
    if "ros2" in sections:
        result["ros2_publish_us"], part = measure_ros2(p, log)
        rows += part
    if "compute" in sections:
        result["compute_per_tick"], part = measure_compute(p, log)
        rows += part
    if "shaping" in sections:
        result["shaping_per_tick"], part = measure_shaping(p, log)
        rows += part
    if "layouts" in sections:
        result["layouts"], part = measure_layouts(p, log)
        rows += part
    if "client" in sections:
        from controller.cli.bench.client import measure_client

        result["client_stream"], part = measure_client(p, log)
        rows += part
    # The JSON keeps the documented order whatever ran.
    result = {key: result[key] for key in (*JSON_KEYS, *FULL_ONLY_JSON_KEYS) if key in result}
    return result, rows, extra
