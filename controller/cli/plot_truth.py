"""The simulator's truth in a recording: where the effector really was, for `cablebot plot`.

A recording of a simulated robot with the physical plant holds `<prefix>/sim/truth` (the
plant's true effector position, `controller.service.simulated.TRUTH_KEY`). `truth_errors`
reads from it, against time, the error of the effector against the set-point (|truth -
set-point|, at the status samples: the set-point comes with them) and of the published pose
against the truth (|pose - truth|, at every pose sample); the truth is interpolated at those
samples' receive times (it is published at the pose rate, so while moving the figures carry
up to a period's skew: at 1 m/s and 500 Hz, 2 mm). `plot_truth` draws one or more recordings
into one figure, e.g. the same run with rigid and with stretching cables.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

TRUTH_FIGURE = "truth"
"""`cablebot plot` writes the truth figure as `<name>-truth.png`."""
_FLOOR_MM = 1e-3
_COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e")


class TruthError(RuntimeError):
    """The recording cannot be read, or holds no truth, poses or set-points."""


@dataclass
class TruthErrors:
    """One recording's errors against the truth (times in s from its first truth sample,
    errors in metres): `status_t_s`/`target_err_m` |truth - set-point| at the status samples,
    `pose_t_s`/`pose_err_m` |published pose - truth| at the pose samples (NaN while the pose
    is not valid); `status_settled`/`pose_settled` the indices of the last sample of each
    stretch of HOLDING (the effector at rest at a point, just before the next move)."""

    label: str
    status_t_s: FloatArray
    target_err_m: FloatArray
    pose_t_s: FloatArray
    pose_err_m: FloatArray
    status_settled: npt.NDArray[np.intp]
    pose_settled: npt.NDArray[np.intp]


def _vec(value: Any) -> tuple[float, float, float] | None:
    if isinstance(value, list) and len(value) == 3:
        try:
            v = (float(value[0]), float(value[1]), float(value[2]))
        except (TypeError, ValueError):
            return None
        if all(math.isfinite(c) for c in v):
            return v
    return None


def has_truth(path: Path, prefix: str | None = None) -> bool:
    """True if the recording holds `<prefix>/sim/truth` (prefix: the recorded one). Raises
    TruthError when the file cannot be read."""
    from mcap.exceptions import McapError

    from controller.cli.record import Recording

    try:
        rec = Recording(path)
        prefix = prefix or rec.recorded_prefix()
        suffix = "/sim/truth"
        for m in rec.messages():
            if (prefix and m.topic == prefix + suffix) or (not prefix and m.topic.endswith(suffix)):
                return True
    except (OSError, ValueError, McapError) as exc:
        raise TruthError(f"cannot read {path}: {exc}") from exc
    return False


def _last_of_holding(states: list[str]) -> npt.NDArray[np.intp]:
    """Indices of the last HOLDING sample of each run of HOLDING samples."""
    out = [
        i
        for i, s in enumerate(states)
        if s == "HOLDING" and (i + 1 == len(states) or states[i + 1] != "HOLDING")
    ]
    return np.asarray(out, dtype=np.intp)


def truth_errors(path: Path, prefix: str | None = None, label: str | None = None) -> TruthErrors:
    """The errors against the truth of one recording (module docstring). Raises TruthError
    when the file cannot be read or holds no truth, or neither set-points nor valid poses."""
    from mcap.exceptions import McapError

    from controller.cli.record import Recording

    tt: list[int] = []
    tp: list[tuple[float, float, float]] = []
    st_t: list[int] = []
    st_sp: list[tuple[float, float, float]] = []
    st_state: list[str] = []
    po_state: list[str] = []
    po_t: list[int] = []
    po_p: list[tuple[float, float, float] | None] = []
    try:
        rec = Recording(path)
        prefix = prefix or rec.recorded_prefix()
        for m in rec.messages():
            if prefix is None and m.topic.endswith("/pose"):
                prefix = m.topic.rsplit("/", 1)[0]
            if prefix is None:
                continue
            if m.topic == f"{prefix}/sim/truth":
                v = _vec(json.loads(m.data).get("position_m"))
                if v is not None:
                    tt.append(m.log_time_ns)
                    tp.append(v)
            elif m.topic == f"{prefix}/status":
                s = json.loads(m.data)
                sp = _vec(s.get("setpoint_m"))
                if sp is not None:
                    st_t.append(m.log_time_ns)
                    st_sp.append(sp)
                    st_state.append(str(s.get("state")))
            elif m.topic == f"{prefix}/pose":
                p = json.loads(m.data)
                po_t.append(m.log_time_ns)
                po_p.append(_vec(p.get("position_m")) if p.get("valid") else None)
                po_state.append(str(p.get("state")))
    except (OSError, ValueError, KeyError, TypeError, AttributeError, McapError) as exc:
        raise TruthError(f"cannot read {path}: {exc}") from exc
    if len(tt) < 2:
        raise TruthError(f"{path}: no simulator truth (<prefix>/sim/truth) in the recording")
    if not st_t and not po_t:
        raise TruthError(f"{path}: no set-points or poses to compare with the truth")
    t0 = tt[0]
    t_truth = (np.asarray(tt, dtype=np.float64) - t0) * 1e-9
    truth = np.asarray(tp, dtype=np.float64)

    def at(times_ns: list[int]) -> tuple[FloatArray, FloatArray]:
        t = (np.asarray(times_ns, dtype=np.float64) - t0) * 1e-9
        cols = [np.interp(t, t_truth, truth[:, k], left=np.nan, right=np.nan) for k in range(3)]
        return t, np.stack(cols, axis=1) if len(t) else np.zeros((0, 3))

    s_t, s_truth = at(st_t)
    target_err = np.linalg.norm(
        s_truth - np.asarray(st_sp, dtype=np.float64).reshape(-1, 3), axis=1
    )
    p_t, p_truth = at(po_t)
    pose = np.asarray(
        [(math.nan,) * 3 if v is None else v for v in po_p], dtype=np.float64
    ).reshape(-1, 3)
    pose_err = np.linalg.norm(pose - p_truth, axis=1)
    return TruthErrors(
        label=label or path.stem,
        status_t_s=s_t,
        target_err_m=np.asarray(target_err, dtype=np.float64),
        pose_t_s=p_t,
        pose_err_m=np.asarray(pose_err, dtype=np.float64),
        status_settled=_last_of_holding(st_state),
        pose_settled=_last_of_holding(po_state),
    )


def _summary(v_m: FloatArray) -> str:
    finite = v_m[np.isfinite(v_m)]
    if finite.size == 0:
        return "no samples"
    return f"median {np.median(finite) * 1e3:.3g} mm, max {np.max(finite) * 1e3:.3g} mm"


def plot_truth(runs: list[TruthErrors], out_path: Path, title: str) -> Path:
    """Draw |truth - set-point| and |published pose - truth| against time for each of `runs`
    into `out_path` (PNG); return it. Raises ImportError without matplotlib, OSError if the
    file cannot be written, ValueError for no runs."""
    if not runs:
        raise ValueError("no recordings to draw")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(13, 7.5), sharex=True)
    try:
        for k, run in enumerate(runs):
            colour = _COLOURS[k % len(_COLOURS)]
            for ax, t, err, settled in (
                (a1, run.status_t_s, run.target_err_m, run.status_settled),
                (a2, run.pose_t_s, run.pose_err_m, run.pose_settled),
            ):
                ax.semilogy(
                    t,
                    np.maximum(err * 1e3, _FLOOR_MM),
                    color=colour,
                    lw=0.5,
                    alpha=0.45,
                    label=f"{run.label}, every sample ({_summary(err)})",
                )
                if len(settled):
                    ax.semilogy(
                        t[settled],
                        np.maximum(err[settled] * 1e3, _FLOOR_MM),
                        "o",
                        color=colour,
                        ms=3.5,
                        mec="k",
                        mew=0.4,
                        label=f"{run.label}, end of each hold ({_summary(err[settled])})",
                    )
        for ax in (a1, a2):
            ax.axhline(1.0, color="k", ls="--", lw=1, label="1 mm")
            ax.grid(True, which="both", alpha=0.25)
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        a1.set_ylabel("|truth - set-point| (mm)")
        a1.set_title("Where the effector is against where it was sent (status samples)")
        a2.set_ylabel("|pose - truth| (mm)")
        a2.set_xlabel("time (s)")
        a2.set_title("The published pose against where the effector is (every pose)")
        fig.suptitle(title)
        fig.text(
            0.01,
            0.01,
            "The simulator's truth interpolated at each sample's receive time (while moving: the "
            "loop's lag, the dynamic loads and the sampling skew);\ndots: the last sample of each "
            f"hold (HOLDING) before the next move. Values below {_FLOOR_MM:g} mm are drawn at "
            f"{_FLOOR_MM:g} mm.",
            fontsize=9,
            color="#555555",
        )
        fig.tight_layout(rect=(0.0, 0.05, 1.0, 1.0))
        out_path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out_path, dpi=110)
    finally:
        plt.close(fig)
    return out_path
