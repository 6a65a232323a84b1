"""`cablebot plot FILE.mcap --out DIR`: the run's figures from any recording.

Four PNG figures (matplotlib, the `plot` extra), named after the recording's file name:

- `<name>-3d.png`: the robot (anchors, poles, footprint, workspace), the cables at the last
  pose, the measured (FPK) path and the set-points;
- `<name>-cable-lengths.png`: each cable's length against time;
- `<name>-fpk-xyz.png`: the FPK x, y and z against time with the set-point;
- `<name>-errors.png`: the tracking error |FPK - set-point| and the FPK residual against time.

Where the numbers come from: the pose samples (every published tick: position, cable lengths,
residual, state) and the status samples (`--status-hz` of the recorder: the set-point, with the
daemon's pose at the same instant, so the tracking error is measured at the status rate). The
robot's geometry is the configuration stored in the recording. `Trace` holds those arrays;
`plot_trace` draws any `Trace`, whoever made it.
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
MAX_POINTS = 20000
"""Lines are thinned to about this many points (a long run stays quick to draw)."""
_CABLE_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")
_STATE_SHADES = {"MOVING": "#1f77b4", "FAULT": "#d62728", "ESTOPPED": "#d62728"}


class PlotError(RuntimeError):
    """The recording cannot be plotted (no pose samples, unreadable file); says why."""


@dataclass
class Trace:
    """What a run's figures need (times in seconds from the first pose; metres).

    Pose rows (N): `t_s`, `position_m` (N, 3, NaN while not valid), `lengths_m` (N, n),
    `residual_m` (NaN while not valid), `state`. Status rows (M): `status_t_s`,
    `setpoint_m` (M, 3, NaN without a set-point), `status_position_m` (M, 3): the daemon's pose
    in the same status reply. `shape`: the robot, if known.
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
    shape: RobotShape | None = None
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
                st_t.append(m.log_time_ns)
                st_sp.append(_xyz(s.get("setpoint_m")))
                st_pos.append(_xyz((s.get("pose") or {}).get("position_m")))
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
        shape=shape,
        notes=notes,
    )


def _thin(n: int) -> slice:
    return slice(None, None, max(1, math.ceil(n / MAX_POINTS)))


def _shade_states(ax: Any, tr: Trace) -> None:
    """Shade the time spans spent MOVING (blue) or in FAULT / ESTOPPED (red)."""
    if not tr.state:
        return
    start = 0
    for i in range(1, len(tr.state) + 1):
        if i == len(tr.state) or tr.state[i] != tr.state[start]:
            colour = _STATE_SHADES.get(tr.state[start])
            if colour is not None:
                end = tr.t_s[i] if i < len(tr.state) else tr.t_s[-1]
                ax.axvspan(tr.t_s[start], end, color=colour, alpha=0.08, lw=0)
            start = i


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
    n = tr.lengths_m.shape[1]
    colours = [_CABLE_COLOURS[i % len(_CABLE_COLOURS)] for i in range(n)]
    th = _thin(len(tr.t_s))
    t = tr.t_s[th]
    has_sp = bool(np.any(np.isfinite(tr.setpoint_m)))
    note_kw: dict[str, Any] = {"ha": "center", "fontsize": 9, "color": "0.3"}
    plt.rcParams.update({"font.size": 11, "axes.titlesize": 12, "figure.titlesize": 14})
    shade_note = "Shaded: moving (blue), fault or e-stop (red)."

    # 1. The robot and the path in 3D.
    fig = plt.figure(figsize=(11, 5.8))
    ax: Any = fig.add_axes((-0.04, 0.0, 0.84, 0.96), projection="3d")
    p = tr.position_m
    valid = np.all(np.isfinite(p), axis=1)
    last = p[valid][-1] if valid.any() else None
    z_scale = 1.0
    if tr.shape is not None:
        A = np.asarray(tr.shape.anchors_m)  # noqa: N806
        for i in range(A.shape[0]):
            ax.plot([A[i, 0]] * 2, [A[i, 1]] * 2, [0.0, A[i, 2]], color="0.45", lw=2.5)
        fp = np.asarray(tr.shape.footprint_m + tr.shape.footprint_m[:1])
        ax.plot(fp[:, 0], fp[:, 1], np.zeros(len(fp)), color="0.6", lw=1, ls=":", label="footprint")
        ws = np.asarray(tr.shape.workspace_m + tr.shape.workspace_m[:1])
        for z in (tr.shape.floor_z_m, tr.shape.top_z_m):
            ax.plot(ws[:, 0], ws[:, 1], np.full(len(ws), z), color="#2ca02c", lw=0.8, ls="--")
        for x, y in tr.shape.workspace_m:
            ax.plot(
                [x, x],
                [y, y],
                [tr.shape.floor_z_m, tr.shape.top_z_m],
                color="#2ca02c",
                lw=0.8,
                ls="--",
            )
        ax.plot([], [], color="#2ca02c", lw=0.8, ls="--", label="workspace")
        ax.scatter(A[:, 0], A[:, 1], A[:, 2], color="k", marker="v", s=50, label="anchors")
        for i in range(A.shape[0]):
            ax.text(A[i, 0], A[i, 1], A[i, 2] * 1.08, f"B{i + 1}", ha="center", fontsize=11)
        if last is not None:
            for i in range(A.shape[0]):
                ax.plot(
                    [A[i, 0], last[0]],
                    [A[i, 1], last[1]],
                    [A[i, 2], last[2]],
                    color=colours[i],
                    lw=1.5,
                    label=f"cable {i + 1}",
                )
        lx, ly = np.ptp(A[:, 0]), np.ptp(A[:, 1])
        zmax = float(np.max(A[:, 2]))
        z_scale = max(1.0, min(3.0, 0.5 * max(lx, ly) / zmax))
        ax.set_box_aspect((lx, ly, zmax * z_scale), zoom=1.0)
        ax.set_zlim(0.0, zmax * 1.1)
    pv = p[th]
    ax.plot(pv[:, 0], pv[:, 1], pv[:, 2], color="#1f77b4", lw=1.8, label="FPK measured")
    if has_sp:
        sp = tr.setpoint_m
        ax.plot(
            sp[:, 0],
            sp[:, 1],
            sp[:, 2],
            ls="none",
            marker="o",
            ms=3,
            mfc="none",
            mec="0.3",
            mew=0.5,
            label="set-point (status samples)",
        )
    if last is not None:
        ax.scatter(*last, color="#d62728", s=40, depthshade=False, label="P, last")
    ax.set_xlabel("x (m)", labelpad=8)
    ax.set_ylabel("y (m)", labelpad=8)
    ax.set_zlabel("z (m)", labelpad=4)
    ax.view_init(elev=26, azim=-62)
    fig.suptitle(f"Robot and path: {tr.title}", y=0.97)
    fig.legend(loc="center right", bbox_to_anchor=(0.99, 0.5), fontsize=10, framealpha=0.9)
    scale_note = f" Vertical scale x{z_scale:.2g}." if z_scale != 1.0 else ""
    fig.text(
        0.45,
        0.025,
        "Cables drawn at the last pose. Measured path: FPK of the encoder lengths, every "
        f"published tick.{scale_note}",
        **note_kw,
    )
    fig.savefig(paths[0], dpi=110)
    plt.close(fig)

    # 2. Cable lengths against time.
    fig, ax = plt.subplots(figsize=(10, 5.6))
    for i in range(n):
        ax.plot(t, tr.lengths_m[th, i], color=colours[i], lw=1.6, label=f"cable {i + 1}")
    _shade_states(ax, tr)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("cable length (m)")
    ax.set_title(f"Cable lengths from the encoders: {tr.title}")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.text(0.45, 0.015, f"Every published tick. {shade_note}", **note_kw)
    fig.tight_layout(rect=(0.0, 0.04, 1.0, 1.0))
    fig.savefig(paths[1], dpi=110)
    plt.close(fig)

    # 3. FPK x, y, z against time with the set-point.
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.8), sharex=True)
    for c, (axis_name, axc) in enumerate(zip("xyz", axes, strict=True)):
        axc.plot(t, p[th, c], color="#1f77b4", lw=1.6, label="FPK (every tick)")
        if has_sp:
            axc.plot(
                tr.status_t_s,
                tr.setpoint_m[:, c],
                "o",
                mfc="none",
                mec="k",
                ms=4,
                label="set-point (status samples)",
            )
        _shade_states(axc, tr)
        axc.set_ylabel(f"{axis_name} (m)")
        axc.grid(True, alpha=0.3)
        col = p[:, c][np.isfinite(p[:, c])]
        if col.size and float(np.ptp(col)) < 0.02:  # a still axis: a centimetre scale, not noise
            mid = float(np.median(col))
            axc.set_ylim(mid - 0.01, mid + 0.01)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, 0.935), ncols=2)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"FPK position vs set-point: {tr.title}")
    fig.text(0.5, 0.012, shade_note, **note_kw)
    fig.tight_layout(rect=(0.0, 0.03, 1.0, 0.9))
    fig.savefig(paths[2], dpi=110)
    plt.close(fig)

    # 4. Tracking error and FPK residual against time, in millimetres.
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(11, 6.8), sharex=True)
    floor = 1e-4
    err = tr.tracking_error_m * 1e3
    if np.any(np.isfinite(err)):
        a1.semilogy(
            tr.status_t_s,
            np.maximum(err, floor),
            "o-",
            color="#1f77b4",
            lw=0.8,
            ms=3,
            label=f"status samples\n(max {np.nanmax(err):.3g} mm)",
        )
        a1.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=10)
    else:
        a1.text(0.5, 0.5, "no set-point in the status samples", transform=a1.transAxes, ha="center")
    _shade_states(a1, tr)
    a1.set_ylabel("|FPK - set-point| (mm)")
    a1.set_title("Tracking error: the daemon's pose minus its set-point, per status sample")
    a1.grid(True, which="both", alpha=0.25)
    res = tr.residual_m[th] * 1e3
    if np.any(np.isfinite(res)):
        a2.semilogy(t, np.maximum(res, floor), color="#2ca02c", lw=0.7, label="every tick")
        a2.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=10)
    _shade_states(a2, tr)
    a2.set_ylabel("FPK residual (mm)")
    a2.set_xlabel("time (s)")
    a2.set_title(f"FPK residual: RMS mismatch of the {n} cable lengths at the solved point")
    a2.grid(True, which="both", alpha=0.25)
    a2.set_xlim(0.0, float(tr.t_s[-1]) if len(tr.t_s) > 1 else 1.0)
    fig.suptitle(f"Errors: {tr.title}")
    fig.text(
        0.45,
        0.012,
        f"{shade_note} Values below {floor:g} mm are drawn at {floor:g} mm.",
        **note_kw,
    )
    fig.tight_layout(rect=(0.0, 0.04, 1.0, 1.0))
    fig.savefig(paths[3], dpi=110)
    plt.close(fig)
    return paths


def cmd_plot(args: argparse.Namespace) -> int:
    """Entry point of `cablebot plot`: 0 when the figures were written, 1 otherwise."""
    path = Path(args.file)
    try:
        tr = trace_from_recording(path, args.prefix)
        paths = plot_trace(tr, Path(args.out), args.name or path.stem)
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
        help="draw a recording's figures (3-D path, cable lengths, position, errors)",
        description=(
            "Read a `cablebot record` file and write four PNG figures into DIR: the robot and "
            "the path in 3-D, the cable lengths, the FPK position against the set-point, and "
            "the tracking error and FPK residual."
        ),
    )
    p.add_argument("file", metavar="FILE.mcap", help="a recording made by `cablebot record`")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the PNG files")
    p.add_argument(
        "--name", default=None, help="file name stem of the figures (default: the recording's)"
    )
    p.add_argument("--prefix", default=None, help="robot prefix (default: the recorded one)")
    p.set_defaults(func=cmd_plot)
