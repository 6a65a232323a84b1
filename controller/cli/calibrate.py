"""`cablebot calibrate collect|solve`: record encoder samples at poses, then fit the anchors.

- `cablebot calibrate collect OUT.csv` (daemon running) records, at each pose, every reel's
  motor position (`axes[].position_rev` of the daemon's status, motor turns as the drive
  reports them) and the pose the controller believes. The operator drives the robot to each
  pose (move, jog, or by hand while disarmed) and presses Enter; or `--auto [N]` visits N
  poses (default: as many as solve recommends) spread over the configured workspace (kept
  `--margin-m` inside it) with the ordinary `move` command, saying up front how long it takes.
  A sample is taken only once the pose is still: for `--settle-s` every published pose stays
  within `--still-m` of their mean. Rows are written and flushed as they come.
- `cablebot calibrate solve SAMPLES.csv [--config FILE]` (default: the built-in robot) fits
  the anchors and the reel offsets (`controller.core.calibration`), prints the changes,
  residuals, observability warnings and the gates; `--write NEW.toml` writes the
  configuration with only the anchor values changed (comments kept), `--write-offsets FILE` a
  homing state file with the fitted offsets; both only when every gate passes.

Exit codes: 0 done (solve: every gate passed); 1 refused, bad input or a failed gate;
2 no daemon answered (collect).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any, Final

from controller.cli.client import (
    ARRIVED_TOL_M,
    EXIT_OK,
    EXIT_REFUSED,
    _interrupted,
    _run,
    robot_of,
    signals_interrupt,
)
from controller.cli.session import (
    DaemonAbsent,
    InputError,
    Refused,
    add_connection_arguments,
    query,
)
from controller.client.link import PoseStream
from controller.client.model import Pose
from controller.client.robot import Robot

Vec3 = tuple[float, float, float]

DEFAULT_MARGIN_RATIO = 0.05
"""`--auto` keeps this fraction of the workspace's smallest extent inside its limits."""

AUTO_RECOMMENDED: Final = object()
"""`--auto` without N: visit `calibration.recommended_poses` poses (a value no N can take,
and not a string, which argparse would convert as if typed)."""

SAMPLE_OVERHEAD_S = 0.5
"""Besides the settle time, what one `--auto` sample costs (command, status queries, the
pose samples before the window starts), for the up-front estimate."""

MAX_READING_AGE_S = 0.5
"""An axis reading older than this is not recorded (the drive stopped reporting)."""


def _fail(msg: str) -> int:
    print(f"cablebot: {msg}", file=sys.stderr)
    return EXIT_REFUSED


# --------------------------------------------------------------------------------------------
# collect


def auto_poses(
    summary: dict[str, Any], n: int, margin_m: float | None, start_m: Sequence[float]
) -> list[Vec3]:
    """`n` poses spread over the workspace described by a status `config` summary.

    Each pose keeps `margin_m` (default: 5 % of the workspace's smallest extent) inside every
    limit: the cube of that half-size around it passes the workspace and cable-length checks
    and, when the robot carries a payload (`payload` and `tension` in the summary), the
    tension rule the controller applies to a target.
    Visiting order: a nearest-neighbour tour from `start_m`. Raises InputError when the
    summary lacks the anchors or limits, or the region holds too few poses.
    """
    from controller.core.calibration import CalibrationError, spread_poses
    from controller.core.kinematics import KinematicsError
    from controller.core.statics import TensionCheck
    from controller.core.workspace import Workspace, layout_geometry
    from controller.service.config import LimitsConfig

    try:
        anchors = [tuple(float(c) for c in r["anchor_m"]) for r in summary["reels"]]
        limits = LimitsConfig(**summary["limits"])
        geom = layout_geometry(anchors, limits)
        ws = Workspace.from_limits(limits, geom)
        ten, load = summary.get("tension"), summary.get("payload")
        tension = (
            None
            if ten is None or load is None
            else TensionCheck(
                anchors,
                float(load["mass_kg"]),
                float(ten["min_n"]),
                float(ten["max_n"]),
                float(ten["margin_n"]),
                str(ten["max_source"]),
            )
        )
    except (KeyError, TypeError, ValueError, KinematicsError) as exc:
        raise InputError(f"the daemon's status has no usable anchors and limits: {exc}") from None
    (x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi) = ws.box()
    lo = (x_lo, y_lo, z_lo)
    hi = (x_hi, y_hi, z_hi)
    if margin_m is None:
        margin_m = DEFAULT_MARGIN_RATIO * min(h - low for h, low in zip(hi, lo, strict=True))
    m = float(margin_m)
    if not (math.isfinite(m) and m >= 0.0):
        raise InputError(f"--margin-m must be a finite number >= 0, got {margin_m}")
    corners = [(dx, dy, dz) for dx in (-m, m) for dy in (-m, m) for dz in (-m, m)]

    def inside(p: Vec3) -> bool:
        return all(
            ws.check_target(q) is None and (tension is None or tension.check(q) is None)
            for q in ((p[0] + dx, p[1] + dy, p[2] + dz) for dx, dy, dz in corners)
        )

    try:
        return spread_poses(n, lo, hi, inside, start_m=start_m)
    except CalibrationError as exc:
        raise InputError(str(exc)) from None


def move_time_s(distance_m: float, speed_mps: float, accel_mps2: float) -> float:
    """The time a straight move of `distance_m` takes with a trapezoidal (or, when short,
    triangular) speed profile from rest to rest. Raises nothing (0 for no distance)."""
    d = max(0.0, float(distance_m))
    if d == 0.0 or speed_mps <= 0.0 or accel_mps2 <= 0.0:
        return 0.0
    if d >= speed_mps * speed_mps / accel_mps2:
        return d / speed_mps + speed_mps / accel_mps2
    return 2.0 * math.sqrt(d / accel_mps2)


def auto_estimate_s(
    start_m: Sequence[float],
    targets: Sequence[Sequence[float]],
    speed_mps: float,
    accel_mps2: float,
    settle_s: float,
) -> tuple[float, float]:
    """(travel in m, time in s) of an `--auto` tour: every move from rest to rest, then the
    settle time and SAMPLE_OVERHEAD_S at each pose."""
    here: Sequence[float] = start_m
    travel_m = time_s = 0.0
    for t in targets:
        d = math.dist(here, t)
        travel_m += d
        time_s += move_time_s(d, speed_mps, accel_mps2) + settle_s + SAMPLE_OVERHEAD_S
        here = t
    return travel_m, time_s


def auto_speed_mps(summary: dict[str, Any], speed_mps: float | None) -> tuple[float, float]:
    """The speed and acceleration the daemon will move `--auto`'s poses at: `--speed` (or the
    robot's default speed) capped at its maximum; its acceleration. Raises InputError when the
    status summary lacks the limits."""
    try:
        lim = summary["limits"]
        v_max = float(lim["max_speed_mps"])
        v = float(lim["default_speed_mps"]) if speed_mps is None else float(speed_mps)
        a = float(lim["max_accel_mps2"])
    except (KeyError, TypeError, ValueError):
        raise InputError("the daemon's status has no speed limits") from None
    return min(v, v_max), a


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min"


class _Poses:
    """The pose samples of a Robot's pose stream, read with deadlines."""

    def __init__(self, stream: PoseStream, timeout_s: float) -> None:
        self.stream = stream
        self.timeout_s = timeout_s

    def next(self, deadline: float) -> Pose | None:
        """The next sample, or None at the deadline. Raises DaemonAbsent when none arrives
        for the reply timeout, Refused when the robot is in FAULT or ESTOPPED."""
        now = time.monotonic()
        if now >= deadline:
            return None
        sample = self.stream.get(min(self.timeout_s, deadline - now))
        if sample is None:
            if time.monotonic() >= deadline:
                return None
            raise DaemonAbsent(f"no pose sample for {self.timeout_s:g} s")
        if sample.state in ("FAULT", "ESTOPPED"):
            raise Refused(f"the robot went {sample.state}: {sample.text()}")
        return sample

    def drain(self) -> None:
        self.stream.drain()


def wait_still(
    poses: _Poses,
    settle_s: float,
    still_m: float,
    timeout_s: float,
    target: Sequence[float] | None = None,
) -> list[float]:
    """Wait until, for `settle_s`, every valid pose (in a still state, at `target` within
    1 mm when given) stays within `still_m` of their mean; return that mean.

    Raises Refused when that does not happen within `timeout_s` (the last pose is named).
    """
    deadline = time.monotonic() + timeout_s
    window: list[tuple[float, list[float]]] = []
    last: Pose | None = None
    while True:
        sample = poses.next(deadline)
        if sample is None:
            where = "no pose" if last is None else last.text()
            raise Refused(f"the pose did not come to rest within {timeout_s:g} s ({where})")
        last = sample
        now = time.monotonic()
        if sample.position_m is None or sample.state in ("MOVING", "ARMING"):
            window.clear()
            continue
        pos = list(sample.position_m)
        if target is not None and (
            sample.state != "HOLDING" or math.dist(pos, target) > ARRIVED_TOL_M
        ):
            window.clear()
            continue
        window.append((now, pos))
        mean = [sum(p[c] for _, p in window) / len(window) for c in range(3)]
        if any(math.dist(p, mean) > still_m for _, p in window):
            window = [window[-1]]  # moving: start the window again from this sample
            continue
        if now - window[0][0] >= settle_s:
            return mean


def read_sample(
    robot: Robot, node_ids: Sequence[int], near: Sequence[float]
) -> tuple[list[float], list[float]]:
    """Motor turns (in `node_ids` order) and the believed pose, from one status query.

    Raises Refused when the pose is not valid, a reel is missing or its reading is stale, or
    the status pose is more than 1 mm from `near` (the robot moved meanwhile).
    """
    st = robot.status()
    pose = st.position_m
    if pose is None:
        raise Refused("the daemon's pose is not valid (home the robot first)")
    if math.dist(pose, near) > ARRIVED_TOL_M:
        raise Refused(f"the robot moved while the sample was taken ({list(pose)} vs {list(near)})")
    by_node = {ax.node_id: ax for ax in st.axes}
    revs: list[float] = []
    for nid in node_ids:
        ax = by_node.get(int(nid))
        if ax is None:
            raise Refused(f"the daemon's status has no axis for node {nid}")
        age = ax.age_s
        rev = ax.position_rev
        if age is None or rev is None or age > MAX_READING_AGE_S:
            raise Refused(f"node {nid}: no fresh encoder reading (age {age} s)")
        revs.append(rev)
    return revs, [float(v) for v in pose]


def _query(session: Any, key: str, payload: Any, timeout_s: float) -> Any:
    # Through this module's `query`, looked up at each call: a test stands in for the daemon
    # by replacing it.
    return query(session, key, payload, timeout_s)


def same_pose_as(
    pose: Sequence[float], earlier: Sequence[Sequence[float]]
) -> tuple[int, float] | None:
    """The 1-based number of the earlier sample nearest `pose` and the distance to it (m) when
    it is closer than the calibration's `DISTINCT_POSE_M` (the fit counts the two as one
    pose), else None. Raises nothing."""
    from controller.core.calibration import DISTINCT_POSE_M

    best: tuple[int, float] | None = None
    for i, other in enumerate(earlier, start=1):
        d = math.dist(pose, other)
        if d < DISTINCT_POSE_M and (best is None or d < best[1]):
            best = (i, d)
    return best


def _open_out(path: str, force: bool) -> IO[str]:
    if os.path.exists(path) and not force:
        raise InputError(f"{path} exists (use --force to overwrite)")
    try:
        return open(path, "w", newline="")
    except OSError as exc:
        raise InputError(f"cannot write {path}: {exc.strerror}") from None


def _positive(name: str, v: float | None, *, allow_none: bool = True) -> None:
    if v is None and allow_none:
        return
    if v is None or not (math.isfinite(v) and v > 0.0):
        raise InputError(f"{name} must be a finite number > 0, got {v}")


def cmd_collect(args: argparse.Namespace, read_line: Callable[[], str] | None = None) -> int:
    """`calibrate collect OUT.csv`: record samples (manual with Enter, or `--auto N`)."""
    try:
        _positive("--speed", args.speed)
        _positive("--settle-s", args.settle_s, allow_none=False)
        _positive("--still-m", args.still_m, allow_none=False)
        if isinstance(args.auto, int) and args.auto < 1:
            raise InputError(f"--auto needs a number of poses >= 1, got {args.auto}")
        if args.count is not None and args.count < 1:
            raise InputError(f"--count must be >= 1, got {args.count}")
        if os.path.exists(args.out) and not args.force:
            raise InputError(f"{args.out} exists (use --force to overwrite)")
    except InputError as exc:
        return _fail(str(exc))
    reader = read_line if read_line is not None else sys.stdin.readline

    def body(session: Any) -> int:
        robot = robot_of(args, session, _query)
        st = robot.status()
        summary = st.raw.get("config") or {}
        node_ids = list(st.node_ids)
        if not node_ids or min(node_ids) < 0:
            raise Refused("the daemon's status does not list its reels")
        pose_now = st.position_m
        targets: list[Vec3] | None = None
        start_m: list[float] = []
        if args.auto is not None:
            if st.state != "HOLDING" or pose_now is None:
                raise Refused(
                    f"--auto moves the robot: it must be armed and holding a valid pose "
                    f"(state {st.state}; run `cablebot arm` first)"
                )
            n_auto = args.auto
            if n_auto is AUTO_RECOMMENDED:
                from controller.core.calibration import recommended_poses

                n_auto = recommended_poses(len(node_ids))
            start_m = [float(v) for v in pose_now]
            targets = auto_poses(summary, n_auto, args.margin_m, start_m)
            speed_mps, accel_mps2 = auto_speed_mps(summary, args.speed)
        stream = robot.poses(timeout_s=args.timeout)
        poses = _Poses(stream, args.timeout)
        from controller.core.calibration import (
            format_sample_row,
            samples_header,
            samples_preamble,
        )

        fh = _open_out(args.out, args.force)
        n_rows = 0
        recorded: list[list[float]] = []
        try:
            fh.write(
                samples_preamble(
                    str(summary.get("name", "?")), node_ids, time.strftime("%Y-%m-%dT%H:%M:%S%z")
                )
            )
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(samples_header(node_ids))
            fh.flush()

            def record(target: Sequence[float] | None) -> None:
                nonlocal n_rows
                poses.drain()
                mean = wait_still(poses, args.settle_s, args.still_m, args.still_timeout_s, target)
                revs, pose = read_sample(robot, node_ids, mean)
                writer.writerow(format_sample_row(revs, pose))
                fh.flush()
                n_rows += 1
                print(
                    f"sample {n_rows}: x={pose[0]:+.4f} y={pose[1]:+.4f} z={pose[2]:+.4f} m  "
                    + " ".join(f"{nid}:{r:.4f}" for nid, r in zip(node_ids, revs, strict=True)),
                    flush=True,
                )
                same = same_pose_as(pose, recorded)
                if same is not None:
                    print(
                        f"cablebot: warning: sample {n_rows} is sample {same[0]}'s pose again "
                        f"({same[1] * 1e3:.2f} mm apart): the fit counts them as one pose; "
                        "move the robot to a new pose before the next sample",
                        file=sys.stderr,
                        flush=True,
                    )
                recorded.append(pose)

            if targets is not None:
                travel_m, total_s = auto_estimate_s(
                    start_m, targets, speed_mps, accel_mps2, args.settle_s
                )
                print(
                    f"visiting {len(targets)} poses: {travel_m:.1f} m at {speed_mps:g} m/s, about "
                    f"{_duration(total_s)}; samples go to {args.out}",
                    flush=True,
                )
                try:
                    with signals_interrupt():  # SIGTERM, SIGHUP: as Ctrl-C
                        t0 = time.monotonic()
                        here: Sequence[float] = start_m
                        for i, target in enumerate(targets, start=1):
                            payload: dict[str, Any] = {"position_m": list(target)}
                            if args.speed is not None:
                                payload["speed_mps"] = args.speed
                            _, left_s = auto_estimate_s(
                                here, targets[i - 1 :], speed_mps, accel_mps2, args.settle_s
                            )
                            here = target
                            print(
                                f"pose {i}/{len(targets)} ({_duration(time.monotonic() - t0)} in,"
                                f" about {_duration(left_s)} left): move to "
                                f"x={target[0]:+.4f} y={target[1]:+.4f} z={target[2]:+.4f} m",
                                flush=True,
                            )
                            robot.send_motion("move", payload, [target], follow=False)
                            record(target)
                except KeyboardInterrupt:  # the robot moves: brake to a hold, as `move --wait`
                    return _interrupted(robot, args)
            else:
                print(
                    "drive the robot to a pose (move, jog, or by hand while disarmed), wait, "
                    "then press Enter to record it; q + Enter (or end of input) to finish",
                    flush=True,
                )
                while args.count is None or n_rows < args.count:
                    print(f"pose {n_rows + 1}: Enter to record, q to finish> ", end="", flush=True)
                    line = reader()
                    if not line or line.strip().lower() in ("q", "quit"):
                        print()
                        break
                    record(None)
        finally:
            fh.close()
            stream.close()
        print(f"{n_rows} sample(s) in {args.out}")
        return EXIT_OK

    return _run(args, body)


# --------------------------------------------------------------------------------------------
# solve


def _mm(v: float | None) -> str:
    return "unbounded" if v is None else f"{v * 1e3:.2f} mm"


def stretch_model(cfg: Any) -> Any:
    """The stretch factors of `cfg`'s elastic cables for `calibrate` (a function of anchors
    and poses: ``(EA + t) / EA`` under the tensions the controller plans there, its tension
    rule with those anchors), or None for rigid cables (no `cable_ea_n`). The function raises
    CalibrationError naming the pose where the statics have no tensions. Raises nothing."""
    if all(r.cable_ea_n is None for r in cfg.reels) or cfg.payload is None or cfg.tension is None:
        return None
    import numpy as np

    from controller.core.calibration import CalibrationError
    from controller.core.kinematics import Geometry, KinematicsError
    from controller.core.stretch import CableStretch
    from controller.service.config import tension_check

    eas = [r.cable_ea_n for r in cfg.reels]
    ones = [1.0] * len(eas)
    hanging = bool(cfg.geometry.hanging)

    def factors(anchors_m: Any, poses_m: Any) -> Any:
        try:
            geom = Geometry(anchors_m, hanging=hanging)
            model = CableStretch(geom, eas, tension_check(cfg.payload, cfg.tension, geom))
        except (KinematicsError, ValueError) as exc:
            raise CalibrationError(f"the cables' stretch at the fitted anchors: {exc}") from None
        out = np.empty((len(poses_m), len(eas)))
        for k, p in enumerate(np.asarray(poses_m, dtype=np.float64).tolist()):
            try:
                out[k] = model.stretched_m(ones, model.tensions_n(p))
            except (KinematicsError, ValueError) as exc:
                raise CalibrationError(f"sample {k + 1}: the cables' stretch: {exc}") from None
        return out

    return factors


def most_stretch_m(stretch: Any, anchors_m: Any, poses_m: Any) -> float:
    """The most any cable stretched at `poses_m` (K, 3) by the factors of `stretch`. Raises
    what `stretch` raises."""
    import numpy as np

    lengths = np.linalg.norm(np.asarray(poses_m)[:, None, :] - np.asarray(anchors_m)[None], axis=2)
    return float(np.max(lengths - lengths / stretch(anchors_m, poses_m)))


def format_report(
    result: Any, config_path: str, samples_path: str, stretch_m: float | None = None
) -> str:
    """The human-readable report of a `Calibration` (`stretch_m`: the most any cable stretched
    at a sample, when the cables' stretch was taken out)."""
    n = len(result.node_ids)
    lines = [
        f"calibration of {config_path} from {samples_path}: {result.poses_m.shape[0]} poses x "
        f"{n} cables ({result.redundancy} redundant equations)",
        "frame: the new anchors are the best-fit rigid (Kabsch) alignment to the configured ones",
    ]
    if stretch_m is not None:
        lines.append(
            "stretch: each cable's length is what its reel paid out, stretched by the tension "
            f"planned at the sample (cable_ea_n; up to {stretch_m * 1e3:.2f} mm)"
        )
    lines += [
        "",
        f"{'anchor':>6} {'node':>4}  {'configured x y z (m)':^29}  {'calibrated x y z (m)':^29}"
        f"  {'|d| mm':>7}{'dx':>7}{'dy':>7}{'dz':>7}{'±1σ mm':>9}",
    ]
    for i in range(n):
        c = result.config_anchors_m[i]
        a = result.anchors_m[i]
        d = (a - c) * 1e3
        lines.append(
            f"{i + 1:>6} {result.node_ids[i]:>4}  {c[0]:+9.4f} {c[1]:+9.4f} {c[2]:+9.4f}  "
            f"{a[0]:+9.4f} {a[1]:+9.4f} {a[2]:+9.4f}  {math.sqrt(float(d @ d)):7.2f}"
            f"{d[0]:+7.1f}{d[1]:+7.1f}{d[2]:+7.1f}{result.anchor_std_m[i] * 1e3:9.2f}"
        )
    lines.append(
        "reel offsets (motor turns at the reference length): "
        + "  ".join(
            f"node {nid}: {o:.6f}"
            for nid, o in zip(result.node_ids, result.offsets_rev, strict=True)
        )
    )
    k, i = result.worst_at
    lines.append(
        f"residuals: RMS {result.rms_m * 1e3:.3f} mm, worst {result.worst_m * 1e3:.3f} mm "
        f"(sample {k + 1}, cable {i + 1}); noise estimate {result.noise_m * 1e3:.3f} mm"
    )
    if result.warnings:
        lines.append("warnings:")
        lines.extend(f"  - {w}" for w in result.warnings)
    lines.append("gates:")
    lines.extend(f"  {'ok  ' if g.ok else 'FAIL'} {g.name}: {g.detail}" for g in result.gates)
    failed = [g.name for g in result.gates if not g.ok]
    lines.append(
        "verdict: PASS (the calibrated anchors may be written)"
        if not failed
        else f"verdict: FAIL ({', '.join(failed)}): keep the configuration; collect better samples"
    )
    return "\n".join(lines)


def _atomic_write(path: str, text: str) -> None:
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def cmd_solve(args: argparse.Namespace) -> int:
    """`calibrate solve SAMPLES.csv [--config FILE]`: fit, report, and write when the gates
    pass (the built-in robot without --config)."""
    import tomllib

    from controller.core.calibration import (
        CalibrationError,
        CalibrationUnavailable,
        Settings,
        calibrate,
        parse_samples,
        replace_anchor_values,
    )
    from controller.core.workspace import Workspace
    from controller.service import offsets as homing
    from controller.service.config import ConfigError, load_config, parse_config
    from controller.service.textfile import NotUtf8Error, read_text

    def refuse(msg: str) -> int:
        if args.json:
            print(json.dumps({"ok": False, "error": msg}))
        return _fail(msg)

    if args.write and args.config is None:
        return refuse(
            "--write edits the robot file given with --config; the built-in robot has none "
            "(`cablebot init-config --example paper-acre` writes a robot file to start from)"
        )
    try:
        cfg = load_config(args.config)  # None: the built-in robot, as `cablebot run` uses
        config_text = "" if args.config is None else read_text(args.config)
    except ConfigError as exc:
        return refuse(str(exc))
    except OSError as exc:
        return refuse(f"cannot read {exc.filename}: {exc.strerror}")
    except NotUtf8Error as exc:
        return refuse(f"{args.config}: {exc}")
    try:
        samples_text = read_text(args.samples)
    except OSError as exc:
        return refuse(f"cannot read {exc.filename}: {exc.strerror}")
    except NotUtf8Error as exc:
        return refuse(f"{args.samples}: {exc}")
    try:
        settings = Settings(
            hold_std_m=args.hold_std_m,
            max_rms_m=args.max_rms_m,
            max_residual_m=args.max_residual_m,
        )
        samples = parse_samples(samples_text, args.samples, cfg.node_ids)
        _, _, (z_lo, z_hi) = Workspace.from_limits(cfg.limits, cfg.geometry).box()
        stretch = stretch_model(cfg)
        result = calibrate(
            cfg.anchors_m,
            [r.reel for r in cfg.reels],
            samples,
            settings,
            pose_height_m=z_hi - z_lo,
            hanging=cfg.geometry.hanging,
            stretch=stretch,
        )
        stretch_m = (
            None if stretch is None else most_stretch_m(stretch, result.anchors_m, result.poses_m)
        )
    except (CalibrationError, CalibrationUnavailable) as exc:
        return refuse(str(exc))

    out = result.as_dict()
    out["stretch_m"] = stretch_m
    written: dict[str, str] = {}
    problem: str | None = None
    if (args.write or args.write_offsets) and not result.ok:
        failed = ", ".join(g.name for g in result.gates if not g.ok)
        problem = f"not writing: the calibration failed its gates ({failed})"
    if problem is None and args.write:
        try:
            new_text = replace_anchor_values(config_text, result.anchors_m, args.config)
            parse_config(tomllib.loads(new_text), args.write)
            _atomic_write(args.write, new_text)
            written["config"] = args.write
        except (CalibrationError, ConfigError) as exc:
            problem = f"not writing {args.write}: {exc}"
        except OSError as exc:
            problem = f"cannot write {args.write}: {exc.strerror}"
    if problem is None and args.write_offsets:
        try:
            record = homing.make_record(
                cfg.name,
                dict(zip(cfg.node_ids, result.offsets_rev.tolist(), strict=True)),
                result.poses_m[-1].tolist(),
            )
            homing.save_offsets(args.write_offsets, record)
            written["offsets"] = args.write_offsets
        except (ValueError, OSError) as exc:
            problem = f"cannot write {args.write_offsets}: {exc}"
    out["written"] = written
    if problem is not None:
        out["error"] = problem
    if args.json:
        print(json.dumps(out, allow_nan=False))
    else:
        print(
            format_report(
                result,
                args.config or "the built-in robot",
                args.samples,
                stretch_m,
            )
        )
        for what, path in written.items():
            print(f"wrote {what}: {path}")
        if "offsets" in written:
            print(
                "the offsets hold only while the drives keep power; restart the daemon with "
                "the new configuration and this state file, or home again"
            )
    if problem is not None:
        return _fail(problem)
    return EXIT_OK if result.ok else EXIT_REFUSED


# --------------------------------------------------------------------------------------------
# Registration


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `calibrate collect` and `calibrate solve`."""
    from controller.core.calibration import Settings

    p = sub.add_parser("calibrate", help="anchor calibration: collect samples, solve for anchors")
    steps = p.add_subparsers(dest="step", metavar="STEP")
    steps.required = True

    c = steps.add_parser("collect", help="record motor turns and poses (daemon running)")
    add_connection_arguments(c)
    c.add_argument("out", metavar="OUT.csv", help="samples file to write")
    c.add_argument(
        "--auto",
        type=int,
        nargs="?",
        const=AUTO_RECOMMENDED,
        default=None,
        metavar="N",
        help=(
            "visit N poses spread over the workspace (without N: as many as calibrate solve "
            "recommends, 28 for four cables); prints the time it will take first"
        ),
    )
    c.add_argument(
        "--count", type=int, default=None, metavar="N", help="manual: stop after N samples"
    )
    c.add_argument("--speed", type=float, default=None, metavar="V", help="--auto move speed, m/s")
    c.add_argument(
        "--margin-m",
        type=float,
        default=None,
        metavar="M",
        help="--auto: keep this far inside the limits (default 5%% of the smallest extent)",
    )
    c.add_argument(
        "--settle-s", type=float, default=0.5, metavar="S", help="still for this long (0.5)"
    )
    c.add_argument(
        "--still-m",
        type=float,
        default=1e-4,
        metavar="M",
        help="still = every pose within this of the mean (1e-4)",
    )
    c.add_argument(
        "--still-timeout-s",
        type=float,
        default=120.0,
        metavar="S",
        help="give up when a pose is not reached and still within this (120)",
    )
    c.add_argument("--force", action="store_true", help="overwrite OUT.csv")
    c.set_defaults(func=cmd_collect)

    s = steps.add_parser("solve", help="fit anchors and reel offsets to samples (offline)")
    s.add_argument("samples", metavar="SAMPLES.csv", help="samples from `calibrate collect`")
    s.add_argument(
        "--config",
        default=None,
        metavar="FILE",
        help="the robot's TOML (default: the built-in robot, as `cablebot run` without --config)",
    )
    s.add_argument(
        "--write",
        default=None,
        metavar="NEW.toml",
        help="write the configuration with the new anchors",
    )
    s.add_argument(
        "--write-offsets",
        default=None,
        metavar="FILE",
        help="write the fitted reel offsets as a homing state file",
    )
    s.add_argument("--json", action="store_true", help="print one JSON object")
    d = Settings()
    s.add_argument(
        "--hold-std-m",
        type=float,
        default=d.hold_std_m,
        metavar="M",
        help=f"hold directions seen worse than this at the config ({d.hold_std_m:g})",
    )
    s.add_argument(
        "--max-rms-m",
        type=float,
        default=d.max_rms_m,
        metavar="M",
        help=f"gate: RMS residual ({d.max_rms_m:g})",
    )
    s.add_argument(
        "--max-residual-m",
        type=float,
        default=d.max_residual_m,
        metavar="M",
        help=f"gate: worst residual ({d.max_residual_m:g})",
    )
    s.set_defaults(func=cmd_solve)
