"""`cablebot bench [--quick] [--json FILE]`: where the time goes, measured on this machine.

Prints one table (figure, value, target, PASS/MISSED, how many repeats) and with `--json FILE`
writes exactly the keys of `JSON_KEYS`. The exit code is 0 even when a target is missed (this is a
measurement); it is 1 only when a figure could not be measured at all.

Method
------
* Micro-benchmarks time a loop of calls with the garbage collector off, on one thread, by the
  thread's CPU time (`time.thread_time_ns`), so that time taken by other processes on a shared
  machine does not count; the wall-clock median (`time.perf_counter_ns`) is shown next to it.
  Each figure is the median over repeats. Ratios are formed per repeat from the two sides run
  back to back (A, B, A, B, ...), then the median of those ratios is taken.
* `fpk_simplified_us` / `fpk_general_us`: `kinematics.three_spheres_equal_height` and
  `kinematics.three_spheres` (scalar, everything from the centres on every call) on the same
  three paper anchors and lengths.
* `fpk4_us`: `kinematics.fpk` on the paper robot's four cables, over a fixed set of poses in the
  workspace whose lengths carry 1 mm of Gaussian noise, so the least-squares refinement runs as
  it does on measured lengths (on exactly consistent lengths `fpk` skips it).
  `scipy_over_fpk4`: `scipy.optimize.least_squares` (default trust-region method, analytic
  Jacobian: the stronger baseline) on the same four spheres, started from the workspace centre.
  The table also shows the ratio with scipy's default finite-difference Jacobian and how far
  apart the solutions are.
* `batch_over_copy`: `kinematics.fpk_batch` on 1,000,000 such noisy rows over `np.copy` of the
  (1,000,000, 4) input. The table also shows the ratio on exactly consistent lengths (IPK of
  the poses), where only the three-spheres seed and the residual check run.
* `statics_us`: `controller.core.statics.CableStatics.solve` (the tension distribution farthest
  from the limits, the closed form for four cables) for the built-in robot's 5 kg payload, over
  a fixed set of workspace poses, per pose; `statics_batch_us`: `CableStatics.solve_batch` on
  100,000 such poses (the vectorised form `cablebot workspace` and path checks use), per pose.
  The table also shows the loop's own check (`TensionCheck.check`: the solve and the reason).
* `sim_plant_rtf`: the physical simulator's real-time factor (simulated seconds per CPU
  second) at 1 kHz: four simulated ODrive axes carrying the built-in robot's payload on elastic
  cables (`drivers.odrive.sim.step_axes` with the `ReelPlant` of `[sim] plant = "physical"`,
  plus each axis's broadcast frames, no bus), holding in position control (`position`) and
  pulling in torque control as the pre-tension does (`torque`). 1 is what keeping up takes; the
  margin above it is what a busy host may take away.
* `decode_frames_per_s`: `controller.cli.bench_rx.poll_rate`, the full receive path on one thread:
  python-can Messages on a `virtual` bus -> `cansimple.decode` -> per-axis reading update and
  stamping, 90 % encoder estimates and 10 % heartbeats for 4 axes.
* `loop`: for each rate a fresh process (`python -m controller.cli.bench loop`, daemon-like: it
  imports only what the daemon imports) starts four simulated ODrive nodes in another process (the
  registry's simulated drives built by `controller.service.simulated.sim_bank`, as `cablebot sim`
  does, at SCHED_FIFO one below the loop when permitted: they stand in for hardware, which a busy
  host does not slow down) on a udp_multicast bus of its own (random group and port), builds the
  bus, driver, `Controller` and `ZenohInterface` with the daemon's own `build_stack`, sets the same
  switch interval, GC freeze, timer slack and scheduling, and runs the controller's `Runner` (the
  daemon's loop itself) in a thread (`controller.service.runner.start_loop`). The robot is armed and
  moved back and forth (1 m/s, all four cables changing), so every tick does the full work: poll,
  FPK, planner, limits, IPK, four Set_Input_Pos frames, one pose put (`publish_every` 1). A fault
  (e.g. a simulator starved on a loaded machine) is counted and shown, then reset and re-armed so
  the run goes on. The loop's own jitter and compute rings are read every 0.1 s, so the percentiles
  cover every tick of the measured window (not only the ring's last 4096); `ticks` and `overruns`
  are the loop's counters over the window. Fractions are of the period. The simulated nodes' tick is
  0.993 ms, not 1 ms: a real ODrive's clock is independent of the host's, so its broadcasts arrive
  at any phase of the loop's tick; two 1 ms grids on the same clock would keep one fixed phase for a
  whole run and make the latency (and the tick's work) a draw of that phase. At 0.7 % the phase
  sweeps a whole 1 ms period every 0.14 s, about 70 times in a run. Each loop figure is the median
  over 3 runs per rate (1 with `--quick`), the rates interleaved (500, 1000, 500, ...). Note that
  udp_multicast delivers the daemon's own frames back to it (python-can cannot filter them), so each
  tick also receives its four Set_Input_Pos frames, which SocketCAN would not. `frames_rx_per_tick`
  / `frames_tx_per_tick` are the driver's frame counters over the measured window divided by its
  ticks: received counts every frame on the bus, the loop's own included.
* `loop.cia402.500`: the same run at 500 Hz on four simulated CiA 402 drives (`[drive] kind =
  "cia402"`, nodes 1..4; the daemon configures them by SDO before its loop runs): each tick
  writes two RPDOs per drive and one SYNC, and every drive answers with its TPDO. No end-to-end
  latency here (the encoder-frame matching is the ODrive codec's); one run (`loop_runs` of them).
* `zenoh_put_us`: the median of `ZenohInterface`'s own timing of `publish_pose` (encode +
  put) over the last 4096 ticks of a 1 kHz run, i.e. in the loop, with a subscriber attached.
* `e2e_p50_us` / `e2e_p99_us` (1 kHz runs): the simulated node's process records
  `time.time_ns()` just before `bus.send` of every encoder frame (node, float32 position); a
  Zenoh subscriber in a third process records `time.time_ns()` when each pose arrives. Every
  process is on this host, so CLOCK_REALTIME is shared. Matching is by value, not by time:
  the pose carries `cable_lengths_m`, which the loop computes as `reel.length_m(position_rev)`
  from the decoded float32, so applying the controller's homed reel models to the logged
  positions reproduces those lengths bit for bit (JSON floats round-trip). Whenever a cable's
  length changes from one received pose to the next, a new encoder frame of that node has
  reached a pose; its latency is the pose's arrival minus the send time of the latest frame of
  that node carrying exactly that value sent before the arrival. Assumption: while the robot
  moves, consecutive encoder values of a node differ (at cruise they are hundreds of float32
  steps apart), so "latest frame with that value" is the frame that produced the change; only
  at the very start and end of a move can two frames 2 ms apart repeat a value, and only if the
  second is sent before the pose arrives does it shorten that sample. Frames
  superseded before any tick used them produce no pose and no sample; a pose dropped by Zenoh
  makes the next pose count, as the subscriber saw it.
* `estop_latency_flood_ms` (`reply_p50`/`reply_p99`, `frame_p50`/`frame_p99`): e-stop while a
  hostile client floods the daemon (`bench_estop_flood`). A daemon-like process
  (`python -m controller.cli.bench daemon`: the daemon's `build_stack` and `start_loop`, the paper
  robot at its default rate with in-process simulated nodes, udp_multicast with hop limit 0)
  is armed. A flooding process keeps `ESTOP_FLOOD_THREADS` queries in flight, in turn a path,
  a move, a set-point put and a home each exactly at its verb's byte cap and malformed only at
  its last byte (so all of it is decoded before the refusal), and the original 10 MB move.
  After a second of flood this process arms the robot and sends e-stops, each to the robot
  holding, after a random 30-80 ms pause, then resets and re-arms it. It times each from just
  before the query to the reply, and to the arrival of the Estop frame of the last axis at an
  observer bus on the same channel (in this process; the kernel's receive stamp, so this
  process's scheduling does not count; a try where the observer's socket dropped a frame uses
  the last one heard and is counted). Percentiles are nearest-rank over the
  tries: of 100, p99 is the second worst; of 50 (`--quick`), the worst. The table also shows
  the flood's rate and any fault of the robot (leaving HOLDING by itself).

* `planning` (`planning.*`): `controller.core.motion_bench.bench_planning` run 3 times (1 with
  `--quick`), timed by the thread's CPU time with the GC off: microseconds per point planned at
  once and appended in chunks, one `advance` (the tick's planner step) with 10 and with 100,000
  points queued, and the 1,000-point circle's time against its length / speed. Target: the
  tick does not depend on the queue, `advance_100k_over_10` (the median of the per-run ratios,
  both sides timed back to back) at most `TARGET_ADVANCE_100K_OVER_10`.
* `stretch_us` (`stretch_us.*`): `controller.cli.stretch_bench.stretch_cost_us`, microseconds
  per call (best of 5 x 500 calls, wall clock) of the loop's IPK and FPK with rigid cables and
  with every cable of the built-in robot at EA 2e5 N; target: each call with stretch under
  `TARGET_STRETCH_US`.
* `sag_us` (`sag_us.*`): `controller.cli.sag_bench.sag_cost_us`, microseconds per call (best
  of 5 runs, the thread's CPU time) of the loop's IPK and FPK with heavy cables, the built-in
  robot's cables as 3 mm steel rope (EA 4.5e5 N, 0.036 kg/m): a tick's plan and paid-out
  lengths, the full solve a move makes every 2.5 cm, the FPK at rest and moving 1 mm and 8 mm
  with the set-point's plan, and without a set-point; target: each call the armed loop makes
  every tick under `TARGET_STRETCH_US`. The compute section's table also shows a tick with
  them.
* `ros2_publish_us` (`ros2_publish_us.*`): `controller.service.ros2.bench.measure_publish_cost`,
  the median per sample of the JSON encoding (`json_encode_us`, the JSON publisher's thread),
  the ROS 2 encoding (`ros2_encode_us`, the ROS 2 node's thread) and the tick's added cost of
  ROS 2 beside JSON (`tick_handoff_us`: the fan-out and the node's one-slot hand-off); the
  table also shows rosbags' encoding of the same messages when it is installed.
* `compute_per_tick` (`compute_per_tick.*`): the controller's own compute without any
  transport (`compute.bench_compute`): a `Controller` at 1 kHz on an `EchoDriver`, whose `poll`
  hands in fresh readings from memory (each axis where the last command put it) and whose
  `command` sends nothing, armed and flying a 4 m loop at 1 m/s, publishing every tick to a
  publisher that drops the sample; the thread's CPU time of each `tick` over 5,000 ticks (2,000
  with `--quick`) after a warm-up, GC frozen as in the daemon; p50, p99 and p99 over the
  period. The table also shows the same with cable stretch, with every reel's spool
  building up (`[[reels]] spool_buildup_factor_m`, `BENCH_BUILDUP_FACTOR_M`) and with cable
  sag (every cable 3 mm steel rope). No bus and no
  other process, so the figure carries over between machines.
* `shaping_per_tick` (`shaping_per_tick.*`, `controller.cli.bench.shaping`): the same tick with
  cable stretch, without and with the default input shaper (on the model's three modes at the
  set-point, following it), `PAIRS` interleaved pairs; p50 and p99 of each, the p99 added and
  the p99 ratio (medians over the pairs). Target: at most `TARGET_SHAPING_ADDED_US` added.
* `layouts` (`layouts.<layout>.*`, `controller.cli.bench.layouts`): the statics (`solve`) and
  the FPK (1 mm of length noise) of every layout of `LAYOUTS` (the paper robot, three cables
  hanging, the Hangprinter v4 and five-anchor files, eight anchors at a box's corners), per
  call at random poses of the workspace and along a path in 1 mm steps (the FPK seeded by the
  last pose), all interleaved in one run; ratios to the paper robot's figures of the same
  kind. Target: eight cables at most `TARGET_LAYOUT_OVER_PAPER4` times the paper robot's four
  at random poses and a tick after the last, for the statics and the FPK.

* `client_stream` (full run only, `FULL_ONLY_SECTIONS`; `--only client`): a 100,000-point path
  streamed to a daemon of the built-in robot by the CLI (`cablebot path FILE --wait`) and by a
  script on the client library (`Robot.stream_path`, `Robot.wait`), back to back, each a fresh
  process timed from start to exit, with its CPU time (`controller.cli.bench.client`). Target:
  the script's wall time over the CLI's at most `TARGET_SCRIPT_OVER_CLI`.

`--only SECTION ...` runs only those sections (`SECTIONS`: kinematics, statics, sim, decode,
loops, estop, planning, stretch, sag, ros2, compute, shaping, layouts; and `client`); the JSON
then holds their keys only.

Layout: `settings` (plans, targets, JSON keys), `timing` (percentiles, interleaved timing),
`figures` (the micro-benchmarks: FPK, batch, statics, simulator, decode), `planning`,
`stretch`, `sag`, `ros2`, `compute`, `shaping`, `layouts`, `client` (one section each: its
figures and rows), `helpers` (the helper processes: simulated drives, pose subscriber), `loop`
(the daemon-like loop run, end-to-end matching), `estop` (the e-stop flood), `table` (rows and
the table), `measure` (each section's figures and rows), `command` (`cablebot bench`),
`vibration` (the controller on the physical plant: `tools/shaping_figures.py` and the shaping
tests), `__main__` (the helper processes' entry).
"""

from __future__ import annotations

from controller.cli.bench.command import cmd_bench, register
from controller.cli.bench.compute import EchoDriver, bench_compute
from controller.cli.bench.estop import (
    bench_estop_flood,
    estop_config_data,
    flood_payloads,
    role_daemon,
    role_flood,
)
from controller.cli.bench.figures import (
    bench_batch,
    bench_decode,
    bench_fpk4,
    bench_sim_plant,
    bench_statics,
    bench_three_spheres,
)
from controller.cli.bench.helpers import role_sim, role_sub
from controller.cli.bench.loop import (
    CIA402_COUNTS_PER_REV,
    bench_loop,
    loop_config_data,
    loop_once,
    match_e2e,
    merge_runs,
    role_loop,
)
from controller.cli.bench.measure import measure
from controller.cli.bench.planning import bench_planning_figures
from controller.cli.bench.ros2 import bench_ros2
from controller.cli.bench.sag import bench_sag
from controller.cli.bench.settings import (
    CHILD_START_TIMEOUT_S,
    CIA402_RATE_HZ,
    COMPUTE_KEYS,
    COMPUTE_RATE_HZ,
    DRAIN_PERIOD_S,
    E2E_MARGIN_US,
    E2E_RATE_HZ,
    ESTOP_FLOOD_THREADS,
    ESTOP_KEYS,
    FULL,
    JSON_KEYS,
    LAYOUT_KEYS,
    LAYOUTS,
    LENGTH_NOISE_M,
    LOOP_KEYS,
    LOOP_RATES_HZ,
    MOVE_POINTS_M,
    MOVE_SPEED_MPS,
    PLANNING_KEYS,
    QUICK,
    ROS2_KEYS,
    SAG_KEYS,
    SECTIONS,
    SEED,
    SIM_TICK_S,
    STRETCH_KEYS,
    TARGET_ADVANCE_100K_OVER_10,
    TARGET_BATCH_OVER_COPY,
    TARGET_COMPUTE_P99_FRAC,
    TARGET_DECODE_FRAMES_PER_S,
    TARGET_ESTOP_FLOOD_P99_MS,
    TARGET_JITTER_P99_FRAC,
    TARGET_LAYOUT_OVER_PAPER4,
    TARGET_OVERRUN_FRAC,
    TARGET_SCIPY_OVER_FPK4,
    TARGET_SIM_RTF,
    TARGET_SIMPLIFIED_OVER_GENERAL,
    TARGET_SIMPLIFIED_US,
    TARGET_STRETCH_US,
    BenchError,
    Plan,
)
from controller.cli.bench.stretch import bench_stretch
from controller.cli.bench.table import Row, format_table, machine_line
from controller.cli.bench.timing import Timed, interleaved, percentile

__all__ = [
    "CHILD_START_TIMEOUT_S",
    "CIA402_COUNTS_PER_REV",
    "CIA402_RATE_HZ",
    "COMPUTE_KEYS",
    "COMPUTE_RATE_HZ",
    "DRAIN_PERIOD_S",
    "E2E_MARGIN_US",
    "E2E_RATE_HZ",
    "ESTOP_FLOOD_THREADS",
    "ESTOP_KEYS",
    "FULL",
    "JSON_KEYS",
    "LAYOUTS",
    "LAYOUT_KEYS",
    "LENGTH_NOISE_M",
    "LOOP_KEYS",
    "LOOP_RATES_HZ",
    "MOVE_POINTS_M",
    "MOVE_SPEED_MPS",
    "PLANNING_KEYS",
    "QUICK",
    "ROS2_KEYS",
    "SAG_KEYS",
    "SECTIONS",
    "SEED",
    "SIM_TICK_S",
    "STRETCH_KEYS",
    "TARGET_ADVANCE_100K_OVER_10",
    "TARGET_BATCH_OVER_COPY",
    "TARGET_COMPUTE_P99_FRAC",
    "TARGET_DECODE_FRAMES_PER_S",
    "TARGET_ESTOP_FLOOD_P99_MS",
    "TARGET_JITTER_P99_FRAC",
    "TARGET_LAYOUT_OVER_PAPER4",
    "TARGET_OVERRUN_FRAC",
    "TARGET_SCIPY_OVER_FPK4",
    "TARGET_SIMPLIFIED_OVER_GENERAL",
    "TARGET_SIMPLIFIED_US",
    "TARGET_SIM_RTF",
    "TARGET_STRETCH_US",
    "BenchError",
    "EchoDriver",
    "Plan",
    "Row",
    "Timed",
    "bench_batch",
    "bench_compute",
    "bench_decode",
    "bench_estop_flood",
    "bench_fpk4",
    "bench_loop",
    "bench_planning_figures",
    "bench_ros2",
    "bench_sag",
    "bench_sim_plant",
    "bench_statics",
    "bench_stretch",
    "bench_three_spheres",
    "cmd_bench",
    "estop_config_data",
    "flood_payloads",
    "format_table",
    "interleaved",
    "loop_config_data",
    "loop_once",
    "machine_line",
    "match_e2e",
    "measure",
    "merge_runs",
    "percentile",
    "register",
    "role_daemon",
    "role_flood",
    "role_loop",
    "role_sim",
    "role_sub",
]
