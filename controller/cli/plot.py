"""`cablebot plot FILE.mcap --out DIR`: the run's figures from any recording.

Four PNG figures (matplotlib, the `plot` extra), named after the recording's file name:

- `<name>-3d.png`: the robot (anchors, poles, footprint, workspace), the cables at the last
  pose, the measured (FPK) path and the set-points;
- `<name>-cable-lengths.png`: each cable's length against time;
- `<name>-fpk-xyz.png`: the FPK x, y and z against time with the set-point;
- `<name>-errors.png`: the tracking error |FPK - set-point| and the FPK residual against time;
- `<name>-speed.png` (recordings only, `SPEED_FIGURE`): the speed against time, set-point and
  measured, with the speed the path asked for, so a user sees where the planner slowed down
  (corners, cable speeds, braking at the end of the queue).

Where the numbers come from: the pose samples (every published tick: position, cable lengths,
residual, state) and the status samples (`--status-hz` of the recorder: the set-point, with the
daemon's pose at the same instant, so the tracking error is measured at the status rate). The
robot's geometry is the configuration stored in the recording. `Trace` holds those arrays;
`plot_trace` draws any `Trace`, whoever made it: `cablebot demo circle` draws its figures
here too, from a `Trace` of what its loop saw, with `Waypoints` (the points it stopped at):
then the cable lengths and the position are drawn against the step, like the paper's figures,
and the errors show the settled error at each point. A path small beside the robot is drawn
zoomed (equal scales), with the whole robot in a plan-view inset.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from controller.cli.shape import RobotShape, ShapeError

FloatArray = npt.NDArray[np.float64]

FIGURES: tuple[str, ...] = ("3d", "cable-lengths", "fpk-xyz", "errors")
"""The figures `plot_trace` writes, as `<name>-<figure>.png`, in this order."""
SPEED_FIGURE = "speed"
"""The figure `plot_speed` writes for a recording, as `<name>-speed.png`."""
SPEED_WINDOW_S = 0.05
"""Speeds are differences of positions at least this far apart in time (less noise)."""
SETPOINT_SPEED_WINDOW_S = 0.15
"""The same for the set-point of a recording whose status samples are dated only by the reply's
arrival (before the daemon stamped them): with the jitter of a query, so over a longer window."""
MAX_POINTS = 20000
"""Lines are thinned to about this many points (a long run stays quick to draw)."""
MAX_MARKERS = 400
"""Set-point samples beyond this many are drawn as a line (markers would hide the path)."""
_CABLE_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")
_FAULT_SHADES = {"FAULT": "#d62728", "ESTOPPED": "#d62728"}
_STATE_SHADES = {"MOVING": "#1f77b4", **_FAULT_SHADES}


class PlotError(RuntimeError):
    """The recording cannot be plotted (no pose samples, unreadable file); says why."""


@dataclass(frozen=True)
class Waypoints:
    """The points a run stopped at, in order, and the pose row taken once settled at each.

    `position_m` (K, 3): row 0 is where the run started (step 0), row k the k-th point it was
    sent to. `row` (K,): strictly increasing indices into the trace's pose rows.
    `step_label`: the x-axis label of the figures drawn against the step.
    """

    position_m: FloatArray
    row: npt.NDArray[np.int64]
    step_label: str = "step"

    def __post_init__(self) -> None:
        """Raises ValueError when the points and rows disagree in number or the rows do not
        increase."""
        if self.position_m.ndim != 2 or self.position_m.shape[1] != 3:
            raise ValueError(f"waypoints must be (K, 3), got {self.position_m.shape}")
        if self.row.shape != (self.position_m.shape[0],):
            raise ValueError(f"{self.position_m.shape[0]} waypoints but {self.row.shape} rows")
        if np.any(np.diff(self.row) <= 0):
            raise ValueError("waypoint rows must increase")

    def settled_error_m(self, position_m: FloatArray) -> FloatArray:
        """|settled position - commanded point| at each point after the start (K - 1,)."""
        return np.asarray(
            np.linalg.norm(position_m[self.row[1:]] - self.position_m[1:], axis=1),
            dtype=np.float64,
        )


@dataclass
class Trace:
    """What a run's figures need (times in seconds from the first pose; metres).

    Pose rows (N): `t_s`, `position_m` (N, 3, NaN while not valid), `lengths_m` (N, n),
    `residual_m` (NaN while not valid), `state`. Status rows (M): `status_t_s`,
    `setpoint_m` (M, 3, NaN without a set-point), `status_position_m` (M, 3): the daemon's pose
    in the same status reply; `setpoint_source` says how often they were taken;
    `requested_speed_mps` (M, NaN off a path): the speed the path asked for;
    `setpoint_stamped`: the status rows are dated by the daemon's tick that computed the
    set-point (else by the reply's arrival, with a query's jitter). `shape`: the robot, if
    known. `waypoints`: the points the run stopped at, if it did.
    """

    title: str
    t_s: FloatArray
    position_m: FloatArray
    lengths_m: FloatArray
    residual_m: FloatArray
    state: list[str]
    status_t_s: FloatArray = field(default_factory=lambda: np.zeros(0))
    setpoint_m: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    status_position_m: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    setpoint_source: str = "status samples"
    requested_speed_mps: FloatArray = field(default_factory=lambda: np.zeros(0))
    setpoint_stamped: bool = False
    shape: RobotShape | None = None
    waypoints: Waypoints | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def tracking_error_m(self) -> FloatArray:
        """|pose - set-point| of each status sample (NaN where either is missing)."""
        if self.status_t_s.shape[0] == 0:
            return np.zeros(0)
        return np.asarray(
            np.linalg.norm(self.status_position_m - self.setpoint_m, axis=1), dtype=np.float64
        )


def _xyz(value: Any) -> tuple[float, float, float]:
    if (
        isinstance(value, list)
        and len(value) == 3
        and all(isinstance(v, int | float) for v in value)
    ):
        return (float(value[0]), float(value[1]), float(value[2]))
    return (math.nan, math.nan, math.nan)


def trace_from_recording(path: Path, prefix: str | None = None) -> Trace:
    """Read a `cablebot record` file into a Trace.

    `prefix` selects the robot when the file holds several (default: the recorded prefix, else
    the first pose key). Raises PlotError when the file cannot be read or holds no poses.
    """
    from mcap.exceptions import McapError

    from controller.cli.record import Recording

    rec = Recording(path)
    pose_t: list[int] = []
    pos: list[tuple[float, float, float]] = []
    lengths: list[list[float]] = []
    resid: list[float] = []
    states: list[str] = []
    st_t: list[int] = []
    st_sp: list[tuple[float, float, float]] = []
    st_pos: list[tuple[float, float, float]] = []
    st_speed: list[float] = []
    n_stamped = 0
    try:
        for m in rec.messages():
            if prefix is None:
                prefix = rec.recorded_prefix() or m.topic.rsplit("/", 1)[0]
            if m.topic == f"{prefix}/pose":
                p = json.loads(m.data)
                pose_t.append(m.publish_time_ns)
                pos.append(_xyz(p.get("position_m")) if p.get("valid") else _xyz(None))
                lengths.append([math.nan if v is None else float(v) for v in p["cable_lengths_m"]])
                r = p.get("residual_m")
                resid.append(math.nan if r is None else float(r))
                states.append(str(p.get("state")))
            elif m.topic == f"{prefix}/status":
                s = json.loads(m.data)
                stamp = s.get("setpoint_stamp_ns")
                stamped = isinstance(stamp, int) and not isinstance(stamp, bool) and stamp > 0
                n_stamped += stamped
                st_t.append(stamp if stamped else m.log_time_ns)
                st_sp.append(_xyz(s.get("setpoint_m")))
                st_pos.append(_xyz((s.get("pose") or {}).get("position_m")))
                want = (s.get("path") or {}).get("speed_mps")
                st_speed.append(float(want) if isinstance(want, int | float) else math.nan)
    except (OSError, ValueError, KeyError, TypeError, McapError) as exc:
        raise PlotError(f"cannot read {path}: {exc}") from exc
    if not pose_t:
        raise PlotError(f"{path}: no pose samples" + (f" under {prefix}" if prefix else ""))
    if len({len(row) for row in lengths}) != 1:
        raise PlotError(f"{path}: the number of cables changes within the recording")
    notes: list[str] = []
    if not rec.complete:
        notes.append("the recording ends early (the recorder was stopped before finishing)")
    shape = None
    summary = rec.config_summary()
    if summary is not None:
        try:
            shape = RobotShape.from_summary(summary)
        except ShapeError as exc:
            notes.append(f"no robot drawn: {exc}")
    else:
        notes.append("the recording holds no configuration: no robot drawn")
    t0 = pose_t[0]
    # Replies can arrive out of order on a loaded machine: the rows in the daemon's time order.
    order = np.argsort(np.asarray(st_t, dtype=np.int64), kind="stable")
    st_t, st_sp, st_pos, st_speed = (
        [rows[i] for i in order] for rows in (st_t, st_sp, st_pos, st_speed)
    )
    return Trace(
        title=f"{path.name} ({prefix})",
        t_s=(np.asarray(pose_t, dtype=np.float64) - t0) * 1e-9,
        position_m=np.asarray(pos, dtype=np.float64),
        lengths_m=np.asarray(lengths, dtype=np.float64),
        residual_m=np.asarray(resid, dtype=np.float64),
        state=states,
        status_t_s=(np.asarray(st_t, dtype=np.float64) - t0) * 1e-9,
        setpoint_m=np.asarray(st_sp, dtype=np.float64).reshape(-1, 3),
        status_position_m=np.asarray(st_pos, dtype=np.float64).reshape(-1, 3),
        requested_speed_mps=np.asarray(st_speed, dtype=np.float64),
        setpoint_stamped=n_stamped > 0,  # by a daemon that stamps (rows without a set-point: NaN)
        shape=shape,
        notes=notes,
    )


def _thin(n: int, most: int = MAX_POINTS) -> slice:
    """Every k-th of `n` rows, k chosen so that about `most` remain."""
    return slice(None, None, max(1, math.ceil(n / most)))


ZOOM_BELOW = 0.25
"""Zoom the 3-D figure to the path when it spans less than this fraction of the robot."""


def zoom_box_3d(anchors_m: FloatArray, path_m: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """The (low, high) corners of a cube around `path_m` for the 3-D figure, or None.

    None when the path spans at least `ZOOM_BELOW` of the anchors' plan-view extent (draw the
    whole robot) or holds no point. Otherwise the cube is centred on the path with 30 % room,
    all three sides equal so that the figure keeps the path's true shape. Raises nothing.
    """
    path_m = path_m[np.all(np.isfinite(path_m), axis=1)]
    robot_span = float(max(np.ptp(anchors_m[:, 0]), np.ptp(anchors_m[:, 1])))
    if path_m.shape[0] == 0 or robot_span <= 0.0:
        return None
    lo = np.min(path_m, axis=0)
    hi = np.max(path_m, axis=0)
    span = float(np.max(hi - lo))
    if span >= ZOOM_BELOW * robot_span:
        return None
    half = max(span, 1e-3) * 0.65
    centre = (lo + hi) / 2.0
    centre[2] = max(float(centre[2]), half)  # keep the cube above the floor (z = 0)
    return centre - half, centre + half


def _reference_m(tr: Trace) -> FloatArray:
    """The commanded path: the waypoints if any, else the finite set-point samples."""
    if tr.waypoints is not None:
        return tr.waypoints.position_m
    sp = tr.setpoint_m
    return sp[np.all(np.isfinite(sp), axis=1)]


def _step_axis(tr: Trace) -> tuple[FloatArray, str]:
    """Where each pose row goes on the x axis of the lengths and position figures, and the
    axis label: the step (settled row of step k at k, rows between placed by time) with
    waypoints, else the time."""
    wp = tr.waypoints
    if wp is None:
        return tr.t_s, "time (s)"
    steps = np.arange(len(wp.row), dtype=np.float64)
    return np.interp(tr.t_s, tr.t_s[wp.row], steps), wp.step_label


def _shade_states(ax: Any, tr: Trace, x: FloatArray) -> None:
    """Shade the spans of `x` spent in FAULT / ESTOPPED (red) and, unless the run went by
    waypoints (its steps show the motion), MOVING (blue)."""
    if not tr.state:
        return
    shades = _STATE_SHADES if tr.waypoints is None else _FAULT_SHADES
    start = 0
    for i in range(1, len(tr.state) + 1):
        if i == len(tr.state) or tr.state[i] != tr.state[start]:
            colour = shades.get(tr.state[start])
            if colour is not None:
                end = x[i] if i < len(tr.state) else x[-1]
                ax.axvspan(x[start], end, color=colour, alpha=0.08, lw=0)
            start = i


def _shade_note(tr: Trace) -> str:
    """What the shading means, for the figure's note."""
    if tr.waypoints is None:
        return "Shaded: moving (blue), fault or e-stop (red)."
    return "Shaded: fault or e-stop (red)."


def _still_axis_limits(values_m: FloatArray, scale_m: float) -> tuple[float, float] | None:
    """Limits for an axis the path hardly moves along (less than 2 cm): its median +- 2.5 %
    of `scale_m` (the path's largest extent), at least +- 1 cm, so that the figure shows the
    coordinate on the scale of the motion, not its noise. None for an axis that moves."""
    v = values_m[np.isfinite(values_m)]
    if v.size == 0 or float(np.ptp(v)) >= 0.02:
        return None
    mid = float(np.median(v))
    half = max(0.01, 0.025 * scale_m)
    return mid - half, mid + half


def plot_trace(tr: Trace, out_dir: Path, name: str) -> list[Path]:
    """Write the four figures (`FIGURES`) as `out_dir/<name>-<figure>.png`; return the paths.

    Raises ImportError without matplotlib (the `plot` extra), OSError if a file cannot be
    written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [out_dir / f"{name}-{fig}.png" for fig in FIGURES]
    plt.rcParams.update({"font.size": 11, "axes.titlesize": 12, "figure.titlesize": 14})
    draw = (_figure_3d, _figure_lengths, _figure_xyz, _figure_errors)
    for figure, path in zip(draw, paths, strict=True):
        fig = figure(plt, tr)
        try:
            fig.savefig(path, dpi=110)
        finally:
            plt.close(fig)
    return paths


def _colours(n: int) -> list[str]:
    return [_CABLE_COLOURS[i % len(_CABLE_COLOURS)] for i in range(n)]


_NOTE: dict[str, Any] = {"ha": "center", "fontsize": 9, "color": "0.3"}
_FLOOR_MM = 1e-4
"""Errors below this are drawn at it (a log scale has no zero)."""


def _figure_3d(plt: Any, tr: Trace) -> Any:
    """The robot and the path in 3-D (the paper's Figure 3). A path small beside the robot
    gets axes zoomed to it (equal scales) and the robot in a plan-view inset."""
    fig = plt.figure(figsize=(11, 5.8))
    ax: Any = fig.add_axes((-0.04, 0.0, 0.84, 0.96), projection="3d")
    p = tr.position_m
    valid = np.all(np.isfinite(p), axis=1)
    last = p[valid][-1] if valid.any() else None
    ref = _reference_m(tr)
    shape = tr.shape
    box = None
    scale_note = ""
    if shape is not None:
        anchors = np.asarray(shape.anchors_m)
        box = zoom_box_3d(anchors, np.vstack([p[valid], ref]))
        if box is None:
            z_scale = _draw_robot_3d(ax, shape)
            scale_note = f" Vertical scale x{z_scale:.2g}." if z_scale != 1.0 else ""
        if last is not None:
            _draw_cables_3d(ax, anchors, last, box)
    pv = p[_thin(len(p))]
    ax.plot(pv[:, 0], pv[:, 1], pv[:, 2], color="#1f77b4", lw=1.8, label="FPK measured")
    if tr.waypoints is not None:
        label = f"commanded ({len(ref) - 1} points)"
        ax.plot(*ref.T, ls="none", marker="o", ms=4.5, mfc="none", mec="k", mew=0.8, label=label)
    elif 0 < len(ref) <= MAX_MARKERS:
        label = f"set-point ({tr.setpoint_source})"
        ax.plot(*ref.T, ls="none", marker="o", ms=3.0, mfc="none", mec="0.3", mew=0.5, label=label)
    elif len(ref):  # many samples: a line, markers would hide the FPK path
        rv = ref[_thin(len(ref))]
        ax.plot(*rv.T, color="k", lw=0.8, ls="--", label=f"set-point ({tr.setpoint_source})")
    if last is not None:
        ax.scatter(*last, color="#d62728", s=40, depthshade=False, label="P, last")
    if box is not None and shape is not None:
        ax.set_xlim(box[0][0], box[1][0])
        ax.set_ylim(box[0][1], box[1][1])
        ax.set_zlim(box[0][2], box[1][2])
        ax.set_box_aspect((1.0, 1.0, 1.0), zoom=0.85)
        scale_note = " Equal scales."
        _draw_plan_inset(fig, shape, p[valid] if valid.any() else ref, box)
    ax.set_xlabel("x (m)", labelpad=8)
    ax.set_ylabel("y (m)", labelpad=8)
    ax.set_zlabel("z (m)", labelpad=4)
    ax.view_init(elev=26, azim=-62)
    fig.suptitle(f"Robot and path: {tr.title}", y=0.97)
    legend_at = (0.99, 0.5) if box is None else (0.99, 0.33)
    fig.legend(loc="center right", bbox_to_anchor=legend_at, fontsize=10, framealpha=0.9)
    fig.text(
        0.45,
        0.025,
        "Cables drawn at the last pose. Measured path: FPK of the encoder lengths, every "
        f"published tick.{scale_note}",
        **_NOTE,
    )
    return fig


def _draw_robot_3d(ax: Any, shape: RobotShape) -> float:
    """Poles, anchors, footprint and the workspace's edges; sets the box aspect and returns the
    vertical exaggeration (at most 3) that keeps a flat robot readable."""
    A = np.asarray(shape.anchors_m)  # noqa: N806
    for i in range(A.shape[0]):
        ax.plot([A[i, 0]] * 2, [A[i, 1]] * 2, [0.0, A[i, 2]], color="0.45", lw=2.5)
    fp = np.asarray(shape.footprint_m + shape.footprint_m[:1])
    ax.plot(fp[:, 0], fp[:, 1], np.zeros(len(fp)), color="0.6", lw=1, ls=":", label="footprint")
    ws_kw: dict[str, Any] = {"color": "#2ca02c", "lw": 0.8, "ls": "--"}
    for (x0, y0, z0), (x1, y1, z1) in shape.workspace_edges_m:
        ax.plot([x0, x1], [y0, y1], [z0, z1], **ws_kw)
    ax.plot([], [], label="workspace", **ws_kw)
    ax.scatter(A[:, 0], A[:, 1], A[:, 2], color="k", marker="v", s=50, label="anchors")
    for i in range(A.shape[0]):
        ax.text(A[i, 0], A[i, 1], A[i, 2] * 1.08, f"B{i + 1}", ha="center", fontsize=11)
    lx, ly = np.ptp(A[:, 0]), np.ptp(A[:, 1])
    zmax = float(np.max(A[:, 2]))
    z_scale = float(max(1.0, min(3.0, 0.5 * max(lx, ly) / zmax)))
    ax.set_box_aspect((lx, ly, zmax * z_scale), zoom=1.0)
    ax.set_zlim(0.0, zmax * 1.1)
    return z_scale


def _draw_cables_3d(
    ax: Any, anchors_m: FloatArray, at_m: FloatArray, box: tuple[FloatArray, FloatArray] | None
) -> None:
    """Each cable from its anchor to `at_m`; in a zoomed box only as far as the box reaches."""
    ends = anchors_m
    if box is not None:
        u = (anchors_m - at_m) / np.linalg.norm(anchors_m - at_m, axis=1)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            to_wall = np.where(u > 0, (box[1] - at_m) / u, (box[0] - at_m) / u)
        reach = np.nanmin(np.where(np.abs(u) > 1e-12, to_wall, np.inf), axis=1)
        ends = at_m + u * reach[:, None]
    for i, colour in enumerate(_colours(anchors_m.shape[0])):
        ax.plot(
            [ends[i, 0], at_m[0]],
            [ends[i, 1], at_m[1]],
            [ends[i, 2], at_m[2]],
            color=colour,
            lw=1.8 if box is not None else 1.5,
            label=f"cable {i + 1}" + ("" if box is None else f" (toward B{i + 1})"),
        )


def _draw_plan_inset(
    fig: Any, shape: RobotShape, path_m: FloatArray, box: tuple[FloatArray, FloatArray]
) -> None:
    """The whole robot seen from above, with the path and the zoomed 3-D view as a red box."""
    from matplotlib.patches import Rectangle

    A = np.asarray(shape.anchors_m)  # noqa: N806
    fig.text(0.89, 0.57, "the 3-D view: red box", ha="center", fontsize=8, color="0.3")
    ins = fig.add_axes((0.80, 0.64, 0.18, 0.28))
    fp = np.asarray(shape.footprint_m + shape.footprint_m[:1])
    ins.plot(fp[:, 0], fp[:, 1], color="0.6", lw=1, ls=":")
    ws = np.asarray(shape.workspace_m + shape.workspace_m[:1])
    ins.plot(ws[:, 0], ws[:, 1], color="#2ca02c", lw=0.8, ls="--")
    ins.plot(A[:, 0], A[:, 1], "kv", ms=5)
    for i in range(A.shape[0]):
        ins.annotate(
            f"B{i + 1}",
            (A[i, 0], A[i, 1]),
            fontsize=8,
            ha="center",
            xytext=(0, 5),
            textcoords="offset points",
        )
    pv = path_m[_thin(len(path_m))]
    ins.plot(pv[:, 0], pv[:, 1], color="#1f77b4", lw=1.5)
    (x0, y0, _), (x1, y1, _) = box
    ins.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="#d62728", lw=1.0))
    ins.set_aspect("equal", adjustable="datalim")
    ins.set_title("plan view", fontsize=9)
    ins.tick_params(labelsize=7)


def _figure_lengths(plt: Any, tr: Trace) -> Any:
    """Each cable's length against time, or against the step (the paper's Figure 4)."""
    fig, ax = plt.subplots(figsize=(10, 5.6))
    x, x_label = _step_axis(tr)
    th = _thin(len(x))
    n = tr.lengths_m.shape[1]
    wp = tr.waypoints
    for i, colour in enumerate(_colours(n)):
        ax.plot(x[th], tr.lengths_m[th, i], color=colour, lw=1.6, label=f"cable {i + 1}")
        if wp is not None:
            ax.plot(np.arange(len(wp.row)), tr.lengths_m[wp.row, i], "o", color=colour, ms=3)
    note = f"Every published tick. {_shade_note(tr)}"
    if wp is not None:
        ax.plot([], [], "o", color="0.3", ms=3, label="settled at a point")
        ax.set_xlim(0, len(wp.row) - 1)
        note = (
            "Lines: every published tick, placed between the steps by time. "
            f"Dots: the lengths once settled at each point.\n{_shade_note(tr)}"
        )
    _shade_states(ax, tr, x)
    ax.set_xlabel(x_label)
    ax.set_ylabel("cable length (m)")
    ax.set_title(f"Cable lengths from the encoders: {tr.title}")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.text(0.45, 0.015, note, **_NOTE)
    fig.tight_layout(rect=(0.0, 0.04 if wp is None else 0.065, 1.0, 1.0))
    return fig


def _figure_xyz(plt: Any, tr: Trace) -> Any:
    """The FPK x, y and z against the commanded points (by step, the paper's Figure 5) or
    against the set-point samples (by time)."""
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.8), sharex=True)
    x, x_label = _step_axis(tr)
    th = _thin(len(x))
    p = tr.position_m
    wp = tr.waypoints
    ref = _reference_m(tr)
    moved = ref if len(ref) else p[np.all(np.isfinite(p), axis=1)]
    scale_m = float(np.max(np.ptp(moved, axis=0))) if len(moved) else 0.0
    has_sp = bool(np.any(np.isfinite(tr.setpoint_m)))
    ref_label = "commanded point" if wp is not None else f"set-point ({tr.setpoint_source})"
    for c, (axis_name, axc) in enumerate(zip("xyz", axes, strict=True)):
        axc.plot(x[th], p[th, c], color="#1f77b4", lw=1.6, label="FPK (every tick)")
        if wp is not None:
            steps = np.arange(len(wp.row))
            axc.plot(steps, wp.position_m[:, c], "o", mfc="none", mec="k", ms=5, label=ref_label)
        elif has_sp and len(tr.status_t_s) <= MAX_MARKERS:
            sp_c = tr.setpoint_m[:, c]
            axc.plot(tr.status_t_s, sp_c, "o", mfc="none", mec="k", ms=4, label=ref_label)
        elif has_sp:  # many samples: a line, markers would hide the FPK
            sth = _thin(len(tr.status_t_s))
            sp_c = tr.setpoint_m[sth, c]
            axc.plot(tr.status_t_s[sth], sp_c, color="k", lw=0.9, ls="--", label=ref_label)
        _shade_states(axc, tr, x)
        axc.set_ylabel(f"{axis_name} (m)")
        axc.grid(True, alpha=0.3)
        lims = _still_axis_limits(ref[:, c] if len(ref) else p[:, c], scale_m)
        if lims is not None:
            axc.set_ylim(*lims)
    if wp is not None:
        axes[-1].set_xlim(0, len(wp.row) - 1)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.935), ncols=2)
    axes[-1].set_xlabel(x_label)
    fig.suptitle(f"FPK position vs set-point: {tr.title}")
    note = _shade_note(tr)
    if wp is not None:
        note = f"The FPK between the points: the loop's lag while moving (see the errors). {note}"
    fig.text(0.5, 0.012, note, **_NOTE)
    fig.tight_layout(rect=(0.0, 0.03, 1.0, 0.9))
    return fig


LEGEND_X_WITH_UM = 1.09
"""Where the legend of an axis with a µm scale on its right starts (axes fraction), clear of
that scale's labels."""


def _mm_to_um(v: Any) -> Any:
    return v * 1e3


def _um_to_mm(v: Any) -> Any:
    return v * 1e-3


def _figure_errors(plt: Any, tr: Trace) -> Any:
    """The tracking error |FPK - set-point| and the FPK residual against time, in mm; the
    tracking error also on a µm scale (right), which reads the settled errors at the points."""
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(11, 6.8), sharex=True)
    floor = _FLOOR_MM
    err = tr.tracking_error_m * 1e3
    if np.any(np.isfinite(err)):
        sth = _thin(len(err))
        style: dict[str, Any] = (
            {"marker": "o", "lw": 0.8, "ms": 3} if len(err) <= MAX_MARKERS else {"lw": 0.7}
        )
        a1.semilogy(
            tr.status_t_s[sth],
            np.maximum(err[sth], floor),
            color="#1f77b4",
            label=f"{tr.setpoint_source}\n(max {np.nanmax(err):.3g} mm)",
            **style,
        )
    else:
        a1.text(0.5, 0.5, "no set-point in the status samples", transform=a1.transAxes, ha="center")
    wp = tr.waypoints
    if wp is not None and len(wp.row) > 1:
        settled = wp.settled_error_m(tr.position_m) * 1e3
        a1.semilogy(
            tr.t_s[wp.row[1:]],
            np.maximum(settled, floor),
            "o",
            color="#d62728",
            ms=3.5,
            label=f"settled at the points\n(max {np.nanmax(settled):.3f} mm)",
        )
    if a1.get_lines():
        a1.axhline(1.0, color="k", ls="--", lw=1, label="1 mm")
        a1.legend(loc="upper left", bbox_to_anchor=(LEGEND_X_WITH_UM, 1.0), fontsize=10)
        # The settled errors are micrometres: a scale in µm on the right reads them directly.
        um = a1.secondary_yaxis("right", functions=(_mm_to_um, _um_to_mm))
        um.set_ylabel("|FPK - set-point| (µm)")
    _shade_states(a1, tr, tr.t_s)
    a1.set_ylabel("|FPK - set-point| (mm)")
    a1.set_title(f"Tracking error: the pose minus the set-point ({tr.setpoint_source})")
    a1.grid(True, which="both", alpha=0.25)
    th = _thin(len(tr.t_s))
    res = tr.residual_m[th] * 1e3
    if np.any(np.isfinite(res)):
        a2.semilogy(tr.t_s[th], np.maximum(res, floor), color="#2ca02c", lw=0.7, label="every tick")
        a2.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=10)
    _shade_states(a2, tr, tr.t_s)
    n = tr.lengths_m.shape[1]
    a2.set_ylabel("FPK residual (mm)")
    a2.set_xlabel("time (s)")
    a2.set_title(f"FPK residual: RMS mismatch of the {n} cable lengths at the solved point")
    a2.grid(True, which="both", alpha=0.25)
    a2.set_xlim(0.0, float(tr.t_s[-1]) if len(tr.t_s) > 1 else 1.0)
    fig.suptitle(f"Errors: {tr.title}")
    fig.text(
        0.45,
        0.012,
        f"{_shade_note(tr)} Values below {floor:g} mm are drawn at {floor:g} mm.",
        **_NOTE,
    )
    fig.tight_layout(rect=(0.0, 0.04, 1.0, 1.0))
    return fig


def speed_mps(
    t_s: FloatArray, position_m: FloatArray, window_s: float = SPEED_WINDOW_S
) -> tuple[FloatArray, FloatArray]:
    """The speed along `position_m` (N, 3) sampled at `t_s` (N,): |p[j] - p[i]| / (t[j] - t[i])
    with j the first sample at least `window_s` after i, at the midpoint time; NaN across a
    missing position. Returns (times, speeds). Raises nothing."""
    n = len(t_s)
    if n < 2:
        return np.zeros(0), np.zeros(0)
    j = np.searchsorted(t_s, t_s + window_s)
    i = np.flatnonzero(j < n)
    j = j[i]
    dt = t_s[j] - t_s[i]
    dist = np.linalg.norm(position_m[j] - position_m[i], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.where(dt > 0, dist / np.where(dt > 0, dt, 1.0), np.nan)
    return 0.5 * (t_s[i] + t_s[j]), np.asarray(v, dtype=np.float64)


def plot_speed(tr: Trace, out_dir: Path, name: str) -> Path:
    """Write the speed figure (`SPEED_FIGURE`) as `out_dir/<name>-speed.png`; return its path.

    Raises ImportError without matplotlib, OSError if the file cannot be written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{name}-{SPEED_FIGURE}.png"
    fig, ax = plt.subplots(figsize=(11, 4.8))
    try:
        _shade_states(ax, tr, tr.t_s)
        t, v = speed_mps(tr.t_s, tr.position_m)
        if len(t):
            sl = _thin(len(t))
            ax.plot(t[sl], v[sl], color="#1f77b4", lw=0.9, label="measured (FPK poses)")
        window = SPEED_WINDOW_S if tr.setpoint_stamped else SETPOINT_SPEED_WINDOW_S
        t, v = speed_mps(tr.status_t_s, tr.setpoint_m, window)
        if len(t):
            style: dict[str, Any] = {"marker": "o", "ms": 3} if len(t) <= MAX_MARKERS else {}
            sl = _thin(len(t))
            ax.plot(t[sl], v[sl], color="k", lw=0.9, ls="--", label="set-point", **style)
        want = tr.requested_speed_mps
        if len(want) == len(tr.status_t_s) and np.any(np.isfinite(want)):
            ax.step(tr.status_t_s, want, where="post", color="#d62728", lw=1.2, label="requested")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("speed (m/s)")
        top = ax.get_ylim()[1]
        ax.set_ylim(0.0, 1.25 * top)  # room for the legend above the lines
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=9, ncol=3)
        ax.set_title(f"Speed along the path: {tr.title}")
        fig.text(
            0.5,
            0.012,
            "Below the requested speed: corners, cable speed limits, speeding up and braking "
            f"(set-point from the status samples). {_shade_note(tr)}",
            **_NOTE,
        )
        fig.tight_layout(rect=(0.0, 0.04, 1.0, 1.0))
        fig.savefig(path, dpi=110)
    finally:
        plt.close(fig)
    return path


def _truth_figure(path: Path, args: argparse.Namespace) -> list[Path]:
    """`<name>-truth.png` when the recording holds the simulator's truth (`<prefix>/sim/truth`),
    with the recordings of `--compare` beside it (`controller.cli.plot_truth`); [] without
    truth. Raises PlotError for a recording that cannot be read or a `--compare` without
    truth, ImportError without matplotlib, OSError if the file cannot be written."""
    from controller.cli.plot_truth import (
        TRUTH_FIGURE,
        TruthError,
        has_truth,
        plot_truth,
        truth_errors,
    )

    try:
        if not has_truth(path, args.prefix):
            if args.compare:
                raise PlotError(f"{path}: no simulator truth to compare with")
            return []
        runs = [truth_errors(path, args.prefix)]
        runs += [truth_errors(Path(other)) for other in args.compare or ()]
    except TruthError as exc:
        raise PlotError(str(exc)) from exc
    name = args.name or path.stem
    title = "Against the simulator's truth: " + ", ".join(r.label for r in runs)
    return [plot_truth(runs, Path(args.out) / f"{name}-{TRUTH_FIGURE}.png", title)]


def cmd_plot(args: argparse.Namespace) -> int:
    """Entry point of `cablebot plot`: 0 when the figures were written, 1 otherwise."""
    path = Path(args.file)
    try:
        tr = trace_from_recording(path, args.prefix)
        paths = plot_trace(tr, Path(args.out), args.name or path.stem)
        paths.append(plot_speed(tr, Path(args.out), args.name or path.stem))
        paths += _truth_figure(path, args)
    except PlotError as exc:
        print(f"cablebot plot: {exc}", file=sys.stderr)
        return 1
    except ImportError as exc:
        print(f"cablebot plot: {exc.name} is missing; install cablebot[plot,view]", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"cablebot plot: {exc}", file=sys.stderr)
        return 1
    for note in tr.notes:
        print(f"note: {note}")
    print(
        f"{len(tr.t_s)} poses over {tr.t_s[-1]:.1f} s, {len(tr.status_t_s)} status samples",
        flush=True,
    )
    for p in paths:
        print(f"wrote {p}", flush=True)
    return 0


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot plot`."""
    p = sub.add_parser(
        "plot",
        help="draw a recording's figures (3-D path, cable lengths, position, errors, speed)",
        description=(
            "Read a `cablebot record` file and write five PNG figures into DIR: the robot and "
            "the path in 3-D, the cable lengths, the FPK position against the set-point, "
            "the tracking error and FPK residual, and the speed (set-point, measured, "
            "requested) against time."
        ),
    )
    p.add_argument("file", metavar="FILE.mcap", help="a recording made by `cablebot record`")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the PNG files")
    p.add_argument(
        "--name", default=None, help="file name stem of the figures (default: the recording's)"
    )
    p.add_argument("--prefix", default=None, help="robot prefix (default: the recorded one)")
    p.add_argument(
        "--compare",
        action="append",
        metavar="OTHER.mcap",
        help="a recording with the simulator's truth drawn beside this one in <name>-truth.png",
    )
    p.set_defaults(func=cmd_plot)
