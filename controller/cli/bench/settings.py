"""The benchmark's settings: how much to measure (`Plan`), the targets, the JSON keys."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Plan:
    """How much to measure: repeats per figure and the loop duration."""

    scalar_repeats: int
    scalar_calls: int
    fpk4_repeats: int
    fpk4_poses: int
    batch_repeats: int
    batch_poses: int
    statics_repeats: int
    statics_poses: int
    statics_batch_poses: int
    sim_seconds: float
    decode_repeats: int
    decode_frames: int
    loop_seconds: float
    loop_runs: int
    estop_tries: int
    planning_repeats: int
    stretch_repeats: int
    ros2_samples: int
    compute_ticks: int
    client_points: int = 100_000


FULL = Plan(
    501, 400, 15, 32, 5, 1_000_000, 51, 200, 100_000, 5.0, 5, 50_000, 10.0, 3, 100, 3, 5, 5000, 5000
)


QUICK = Plan(
    101,
    400,
    5,
    16,
    3,
    1_000_000,
    11,
    100,
    100_000,
    1.0,
    3,
    20_000,
    2.0,
    1,
    50,
    1,
    3,
    2000,
    2000,
    client_points=10_000,
)


LENGTH_NOISE_M = 1e-3
"""Standard deviation of the noise put on the cable lengths for `fpk4` and the batch."""


LOOP_RATES_HZ = (500, 1000)


CIA402_RATE_HZ = 500
"""The rate of the loop run on simulated CiA 402 drives (13 frames a tick fill 66 % of a
1 Mbit/s bus at 500 Hz; 1 kHz would not fit)."""


E2E_RATE_HZ = 1000


MOVE_SPEED_MPS = 1.0


MOVE_POINTS_M = ((-2.0, -1.0, 2.0), (2.0, 1.0, 3.0))


DRAIN_PERIOD_S = 0.1


SIM_TICK_S = 0.000993
"""The simulated nodes' clock runs 0.7 % fast (see the module docstring: phase sweep)."""


CHILD_START_TIMEOUT_S = 30.0


SEED = 8


TARGET_SIMPLIFIED_OVER_GENERAL = 0.6


TARGET_SIMPLIFIED_US = 2.0


TARGET_SCIPY_OVER_FPK4 = 100.0


TARGET_BATCH_OVER_COPY = 20.0


TARGET_DECODE_FRAMES_PER_S = 20_000.0


TARGET_SIM_RTF = 1.0


TARGET_JITTER_P99_FRAC = 0.10


TARGET_COMPUTE_P99_FRAC = 0.25


TARGET_OVERRUN_FRAC = 0.001


E2E_MARGIN_US = 300.0


TARGET_ESTOP_FLOOD_P99_MS = 50.0


ESTOP_FLOOD_THREADS = 4
"""Queries the flooding client keeps in flight."""


LOOP_KEYS = (
    "ticks",
    "overruns",
    "jitter_p50_frac",
    "jitter_p99_frac",
    "compute_p50_frac",
    "compute_p99_frac",
)


FULL_ONLY_JSON_KEYS = ("client_stream",)
"""The keys of `FULL_ONLY_SECTIONS`, after `JSON_KEYS` in the JSON of a full run."""


JSON_KEYS = (
    "fpk_simplified_us",
    "fpk_general_us",
    "fpk_simplified_over_general",
    "fpk4_us",
    "scipy_over_fpk4",
    "batch_over_copy",
    "statics_us",
    "statics_batch_us",
    "sim_plant_rtf",
    "decode_frames_per_s",
    "zenoh_put_us",
    "loop",
    "e2e_p50_us",
    "e2e_p99_us",
    "estop_latency_flood_ms",
    "planning",
    "stretch_us",
    "sag_us",
    "ros2_publish_us",
    "compute_per_tick",
    "shaping_per_tick",
    "layouts",
)


SECTIONS = (
    "kinematics",
    "statics",
    "sim",
    "decode",
    "loops",
    "estop",
    "planning",
    "stretch",
    "sag",
    "ros2",
    "compute",
    "shaping",
    "layouts",
)
"""The benchmark's sections, in the order they run (`cablebot bench --only NAME ...`)."""


FULL_ONLY_SECTIONS = ("client",)
"""Sections the full run adds after `SECTIONS` (not `--quick`: the client section streams a
100,000-point path twice, about a minute of flight); `--only client` runs it alone."""


CLIENT_KEYS = (
    "points",
    "flight_s",
    "cli_s",
    "script_s",
    "script_over_cli",
    "cli_cpu_s",
    "script_cpu_s",
    "cpu_script_over_cli",
)


CLIENT_SPACING_M = 100e-6
"""The client section's spiral: its points this far apart along it."""


CLIENT_SPEED_MPS = 0.3
"""The client section's path speed: 3,000 points a second, within the planner's 4,000 a second
at the built-in robot's 500 Hz."""


TARGET_SCRIPT_OVER_CLI = 1.1
"""A path streamed from a script on the client library takes at most 10 % longer, wall clock,
than the CLI takes to stream the same path (both paced by the daemon's queue, so both are
mostly the flight: the ratio shows the library's own start and end, not the robot's)."""


ESTOP_KEYS = ("reply_p50", "reply_p99", "frame_p50", "frame_p99")


TARGET_ADVANCE_100K_OVER_10 = 2.0
"""The tick's cost must not depend on the queue: `advance` with 100,000 points queued over
`advance` with 10, the median of per-run ratios (both sides timed back to back by thread CPU
time, GC off). A tick linear in the queue would be about 10,000 times dearer; measured runs
give 0.9-1.1 on a 2-vCPU machine at load 6-7, so 2 leaves room for a loaded machine's noise
(cache misses after pre-emption count in CPU time) and still catches a tick that grows with
the queue by more than that.
"""


PLANNING_KEYS = (
    "plan_us_per_point",
    "append_us_per_point",
    "advance_us_10",
    "advance_us_100k",
    "advance_100k_over_10",
    "circle_s",
    "circle_ideal_s",
)


TARGET_STRETCH_US = 50.0
"""IPK and FPK with cable stretch, four cables, per call."""


STRETCH_KEYS = (
    "ipk_rigid",
    "ipk_stretch",
    "ipk_stretch_derivative",
    "fpk_rigid",
    "fpk_stretch_rest",
    "fpk_stretch_moving",
    "fpk_stretch_fast",
    "fpk_stretch_no_setpoint",
    "fpk_stretch_measured",
    "statics",
)


SAG_KEYS = (
    "ipk_sag",
    "ipk_sag_base",
    "fpk_sag_rest",
    "fpk_sag_moving",
    "fpk_sag_fast",
    "fpk_sag_no_setpoint",
    "sag_solve",
)


ROS2_KEYS = (
    "json_encode_us",
    "ros2_encode_us",
    "tick_handoff_us",
    "ros2_vs_json",
)


COMPUTE_RATE_HZ = 1000


COMPUTE_KEYS = ("ticks", "p50_us", "p99_us", "p99_frac")


class BenchError(RuntimeError):
    """A figure could not be measured (a helper process failed, no samples, ...)."""


TARGET_SHAPING_ADDED_US = 50.0
"""Input shaping (the default train on the model's three modes, following the set-point) adds
at most this to the tick's 99th percentile."""


SHAPING_KEYS = (
    "p50_us_off",
    "p99_us_off",
    "p50_us_on",
    "p99_us_on",
    "added_p99_us",
    "on_over_off",
    "p99_us_two_passes",
    "added_p99_us_two_passes",
)


LAYOUTS = ("paper-4", "triangle-3", "hangprinter-4", "hangprinter-5", "cube-8")
"""The layouts section's robots: the paper robot (the reference), three cables hanging from a
triangle, the Hangprinter v4 and five-anchor files, eight anchors at a box's corners (among)."""
LAYOUT_KEYS = (
    "statics_us",
    "statics_tick_us",
    "fpk_us",
    "fpk_tick_us",
    "statics_over_paper4",
    "fpk_over_paper4",
    "statics_tick_over_paper4",
    "fpk_tick_over_paper4",
)
TARGET_LAYOUT_OVER_PAPER4 = 2.0
"""Eight cables' statics and FPK per call over the paper robot's four, at random poses and a
tick after the last."""
