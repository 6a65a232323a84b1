"""`cablebot plot`'s drawing of a `Trace` (no recording, no daemon): waypoints put the lengths
and position figures on a step axis and mark the settled error; a small path is zoomed with the
robot in a plan-view inset; many set-point samples are drawn as a line; an axis the path does
not move along is shown on the scale of the motion."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller.cli import plot
from controller.cli.shape import RobotShape
from controller.core.kinematics import Geometry, ipk
from controller.core.motion import circle_path
from controller.service.config import load_config

pytest.importorskip("matplotlib")


@pytest.fixture
def figures(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[Any]]:
    """The matplotlib figures `plot_trace` closes, in order (3-D, lengths, xyz, errors)."""
    import matplotlib.pyplot as plt

    seen: list[Any] = []
    real_close = plt.close

    def close(fig: Any = None) -> None:
        seen.append(fig)
        real_close(fig)

    monkeypatch.setattr(plt, "close", close)
    yield seen


def _trace(
    points_m: np.ndarray, *, per_point: int = 5, status_every: int = 1, waypoints: bool = False
) -> plot.Trace:
    """A run that stops `per_point` rows at each of `points_m` (the FPK exactly there), with
    the set-point every `status_every`-th row, on the paper robot."""
    cfg = load_config(None)
    pos = np.repeat(points_m, per_point, axis=0)
    n = len(pos)
    t = np.arange(n, dtype=np.float64) * 0.1
    st = slice(None, None, status_every)
    return plot.Trace(
        title="test",
        t_s=t,
        position_m=pos,
        lengths_m=np.asarray(ipk(Geometry(cfg.anchors_m), pos)),
        residual_m=np.full(n, 1e-6),
        state=["HOLDING"] * n,
        status_t_s=t[st],
        setpoint_m=pos[st].copy(),
        status_position_m=pos[st].copy(),
        shape=RobotShape.from_summary(cfg.summary()),
        waypoints=(
            plot.Waypoints(points_m, np.arange(len(points_m)) * per_point + per_point - 1)
            if waypoints
            else None
        ),
    )


def _circle(radius_m: float, steps: int = 12) -> np.ndarray:
    return np.asarray(circle_path(radius_m, (0.0, 0.0), 2.0, steps))


def test_waypoints_must_match_their_rows() -> None:
    pts = _circle(2.0, 4)
    with pytest.raises(ValueError, match="5 waypoints but"):
        plot.Waypoints(pts, np.arange(4))
    with pytest.raises(ValueError, match="must increase"):
        plot.Waypoints(pts, np.array([0, 1, 1, 2, 3]))
    with pytest.raises(ValueError, match=r"\(K, 3\)"):
        plot.Waypoints(pts[:, :2], np.arange(5))
    wp = plot.Waypoints(pts, np.arange(5) * 2)
    pos = np.repeat(pts, 2, axis=0)
    pos[4, 2] += 0.003  # the settled row of point 2
    assert wp.settled_error_m(pos) == pytest.approx([0.0, 0.003, 0.0, 0.0])


def test_waypoints_put_lengths_and_position_on_a_step_axis(
    tmp_path: Path, figures: list[Any]
) -> None:
    tr = _trace(_circle(20.0), waypoints=True)
    assert tr.waypoints is not None
    tr.waypoints = plot.Waypoints(
        tr.waypoints.position_m, tr.waypoints.row, "step (30 degrees each)"
    )
    plot.plot_trace(tr, tmp_path, "c")
    lengths_ax = figures[1].get_axes()[0]
    assert lengths_ax.get_xlabel() == "step (30 degrees each)"
    assert lengths_ax.get_xlim() == (0.0, 12.0)
    dots = [ln for ln in lengths_ax.get_lines() if ln.get_marker() == "o" and len(ln.get_xdata())]
    assert len(dots) == 4  # the settled lengths of each cable, at the steps 0..12
    assert list(dots[0].get_xdata()) == list(range(13))
    assert list(dots[0].get_ydata()) == pytest.approx(list(tr.lengths_m[tr.waypoints.row, 0]))
    x_ax = figures[2].get_axes()[0]
    commanded = [ln for ln in x_ax.get_lines() if ln.get_label() == "commanded point"]
    assert len(commanded) == 1 and list(commanded[0].get_xdata()) == list(range(13))


def test_settled_error_is_marked_on_the_error_figure(tmp_path: Path, figures: list[Any]) -> None:
    tr = _trace(_circle(20.0), waypoints=True)
    assert tr.waypoints is not None
    tr.position_m[tr.waypoints.row[5], 2] += 0.25e-3
    plot.plot_trace(tr, tmp_path, "c")
    a1 = figures[3].get_axes()[0]
    labels = [ln.get_label() for ln in a1.get_lines()]
    assert "settled at the points\n(max 0.250 mm)" in labels
    assert "1 mm" in labels
    # the settled errors are micrometres: the axis has a µm scale on its right (1 mm = 1000 µm)
    um = [ax for ax in a1.child_axes if "µm" in ax.get_ylabel()]
    assert len(um) == 1
    assert um[0].get_ylim() == pytest.approx([v * 1e3 for v in a1.get_ylim()])


def test_a_small_path_is_zoomed_with_the_robot_in_an_inset(
    tmp_path: Path, figures: list[Any]
) -> None:
    tr = _trace(_circle(1.0))
    plot.plot_trace(tr, tmp_path, "small")
    axes = figures[0].get_axes()
    assert len(axes) == 2 and axes[1].get_title() == "plan view"
    assert tr.shape is not None
    box = plot.zoom_box_3d(np.asarray(tr.shape.anchors_m), tr.position_m)
    assert box is not None
    lo, hi = box
    assert axes[0].get_xlim() == pytest.approx((lo[0], hi[0]))
    tr_big = _trace(_circle(20.0))
    figures.clear()
    plot.plot_trace(tr_big, tmp_path, "big")
    assert len(figures[0].get_axes()) == 1
    x0, x1 = figures[0].get_axes()[0].get_xlim()
    assert x0 <= -40.0 and x1 >= 40.0


def test_many_set_point_samples_are_a_line_few_are_markers(
    tmp_path: Path, figures: list[Any]
) -> None:
    pts = _circle(20.0, 72)
    dense = _trace(pts, per_point=10)  # 730 samples > MAX_MARKERS
    assert len(dense.status_t_s) > plot.MAX_MARKERS
    plot.plot_trace(dense, tmp_path, "dense")
    sp = [ln for ln in figures[2].get_axes()[0].get_lines() if "set-point" in ln.get_label()]
    assert (
        len(sp) == 1 and sp[0].get_marker() in ("None", "", None) and sp[0].get_linestyle() == "--"
    )
    figures.clear()
    sparse = _trace(pts, per_point=10, status_every=10)  # 73 samples
    plot.plot_trace(sparse, tmp_path, "sparse")
    sp = [ln for ln in figures[2].get_axes()[0].get_lines() if "set-point" in ln.get_label()]
    assert len(sp) == 1 and sp[0].get_marker() == "o"


def test_an_axis_the_path_does_not_move_along_is_drawn_to_the_motion_s_scale(
    tmp_path: Path, figures: list[Any]
) -> None:
    plot.plot_trace(_trace(_circle(20.0)), tmp_path, "circle")
    z_ax = figures[2].get_axes()[2]
    assert z_ax.get_ylim() == pytest.approx((1.0, 3.0))  # 2.5 % of the 40 m circle
    figures.clear()
    still = _trace(np.array([[1.0, 2.0, 3.0]] * 4))
    plot.plot_trace(still, tmp_path, "still")
    for c, axc in enumerate(figures[2].get_axes()):
        mid = still.position_m[0, c]
        assert axc.get_ylim() == pytest.approx((mid - 0.01, mid + 0.01))  # at least 1 cm


def test_speed_is_measured_over_a_window_and_nan_across_a_missing_pose() -> None:
    t = np.arange(0.0, 1.0, 0.01)
    pos = np.stack([0.2 * t, np.zeros_like(t), np.full_like(t, 2.0)], axis=1)
    pos[50] = np.nan
    mid, v = plot.speed_mps(t, pos, window_s=0.05)
    assert len(mid) == len(v) and np.all(np.diff(mid) > 0)
    good = np.isfinite(v)
    assert np.allclose(v[good], 0.2) and (~good).sum() == 2  # the two windows that end at 50
    assert plot.speed_mps(t[:1], pos[:1])[0].size == 0


def test_the_speed_figure_draws_set_point_measured_and_requested(
    tmp_path: Path, figures: list[Any]
) -> None:
    tr = _trace(np.asarray(circle_path(0.5, (0.0, 0.0), 2.0, 24)), per_point=3)
    tr.requested_speed_mps = np.full(len(tr.status_t_s), 0.3)
    tr.state = ["MOVING"] * len(tr.t_s)
    path = plot.plot_speed(tr, tmp_path, "run")
    assert path == tmp_path / f"run-{plot.SPEED_FIGURE}.png"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (ax,) = figures[-1].axes
    labels = [line.get_label() for line in ax.get_lines()]
    assert labels == ["measured (FPK poses)", "set-point", "requested"]
    requested = ax.get_lines()[2].get_ydata()
    assert np.allclose(requested, 0.3)


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b"", "the file is empty (0 bytes)"),
        (b"x,y,z\n0,0,2\n", "not an MCAP file (it does not start with MCAP's magic bytes)"),
        (b"\x89MCAP0\r\n", "the file is cut off after 8 bytes, before its first record"),
        (b"\x89MC", "the file is cut off after 3 bytes, before its first record"),
    ],
)
def test_a_file_that_is_no_recording_is_named_with_its_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes, reason: str
) -> None:
    from controller.cli import exitcodes, main

    path = tmp_path / "run.csv"
    path.write_bytes(content)
    assert main(["plot", str(path), "--out", str(tmp_path / "out")]) == exitcodes.REFUSED
    err = capsys.readouterr().err
    assert err == f"cablebot plot: cannot read {path}: not a cablebot recording: {reason}\n"
    assert main(["replay", str(path)]) == exitcodes.REFUSED
    err = capsys.readouterr().err
    assert err == f"cablebot replay: cannot read {path}: not a cablebot recording: {reason}\n"


def _square_side_recording(path: Path, *, stamped: bool) -> None:
    """A recording of a set-point moving at 0.5 m/s along x for 2 s (pose at 250 Hz), with the
    status sampled at 20 Hz whose replies reach the recorder late by 0 to 60 ms, some after
    the next one (as on a loaded machine); `stamped`: the daemon dates each set-point."""
    from controller.cli.record import McapRecorder

    pytest.importorskip("mcap")
    rng = np.random.default_rng(7)
    t0_ns = 1_800_000_000 * 10**9
    prefix = "cablebot/sq"
    msgs: list[tuple[int, str, bytes]] = []
    for k in range(500):
        t_ns = t0_ns + k * 4_000_000
        x = 0.5 * k * 0.004
        pose = {
            "seq": k,
            "stamp_ns": t_ns,
            "position_m": [x, 0.0, 2.0],
            "cable_lengths_m": [1.0, 1.0, 1.0, 1.0],
            "residual_m": 0.0,
            "valid": True,
            "state": "MOVING",
        }
        msgs.append((t_ns + 1_000_000, f"{prefix}/pose", json.dumps(pose).encode()))
    for k in range(40):
        t_ns = t0_ns + k * 50_000_000
        x = 0.5 * k * 0.05
        status: dict[str, Any] = {
            "state": "MOVING",
            "setpoint_m": [x, 0.0, 2.0],
            "pose": {"valid": True, "position_m": [x, 0.0, 2.0]},
            "path": {"speed_mps": 0.5},
        }
        if stamped:
            status["setpoint_stamp_ns"] = t_ns
        late_ns = int(rng.uniform(0.0, 60e6))
        msgs.append((t_ns + late_ns, f"{prefix}/status", json.dumps(status).encode()))
    with open(path, "wb") as out:
        rec = McapRecorder(out, prefix, flush_s=1.0)
        for recv_ns, key, data in sorted(msgs):
            rec.add(key, data, recv_ns)
        rec.close()


def test_the_set_point_speed_is_dated_by_the_daemon_not_by_the_replys_arrival(
    tmp_path: Path,
) -> None:
    """Status replies late and out of order made a steady 0.5 m/s set-point look like dips to
    half speed and spikes; dated by the tick that computed it, it is 0.5 m/s throughout."""
    stamped = tmp_path / "stamped.mcap"
    _square_side_recording(stamped, stamped=True)
    tr = plot.trace_from_recording(stamped)
    assert tr.setpoint_stamped
    assert np.all(np.diff(tr.status_t_s) > 0)  # in the daemon's order
    _, v = plot.speed_mps(tr.status_t_s, tr.setpoint_m, plot.SPEED_WINDOW_S)
    assert np.allclose(v, 0.5, atol=1e-6), v
    # an older recording (no stamps): dated by arrival, the same run is off by far more
    old = tmp_path / "old.mcap"
    _square_side_recording(old, stamped=False)
    tr_old = plot.trace_from_recording(old)
    assert not tr_old.setpoint_stamped
    _, v_old = plot.speed_mps(tr_old.status_t_s, tr_old.setpoint_m, plot.SPEED_WINDOW_S)
    assert np.nanmax(np.abs(v_old - 0.5)) > 0.1


def test_the_workspace_of_a_hangprinter_is_drawn_as_its_true_shape() -> None:
    """The 3-D figure draws the workspace's edges (`RobotShape.workspace_edges_m`: the faces
    of the solid the daemon enforces, here the Hangprinter v4's hull moved in and cut by its
    print radius), each edge once, and every drawn end point is in the workspace."""
    import matplotlib.pyplot as plt

    from controller.cli.configs import find_example
    from controller.core.workspace import Workspace

    cfg = load_config(find_example("hangprinter-v4.toml"))
    shape = RobotShape.from_summary(cfg.summary())
    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    fig = plt.figure()
    try:
        ax = fig.add_subplot(projection="3d")
        plot._draw_robot_3d(ax, shape)
        drawn = [line.get_data_3d() for line in ax.get_lines() if line.get_color() == "#2ca02c"]
    finally:
        plt.close(fig)
    ends = {
        tuple(round(float(c[k]), 9) for c in xyz) for xyz in drawn if len(xyz[0]) for k in (0, -1)
    }
    want = {tuple(round(c, 9) for c in p) for e in shape.workspace_edges_m for p in e}
    assert ends == want
    assert len([d for d in drawn if len(d[0])]) == len(shape.workspace_edges_m)
    mid = np.mean(np.array(sorted(want)), axis=0)
    for p in want:
        q = np.asarray(p)
        inward = q + 1e-6 * (mid - q) / np.linalg.norm(mid - q)
        assert ws.check_point(inward.tolist()) is None, p
