"""`cablebot demo circle --plot`: matplotlib is checked before the run; a small path is drawn
zoomed with equal scales and the whole robot in an inset."""

from __future__ import annotations

import importlib.util
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller.cli import demo, main, plot
from controller.core.motion import circle_path
from controller.service.config import load_config
from tests.cli.test_demo import _synthetic_run, png_size


def test_plot_without_matplotlib_fails_before_the_run(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    real = importlib.util.find_spec

    def find_spec(name: str, *args: Any) -> Any:
        return None if name == "matplotlib" else real(name, *args)

    def run_circle(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the circle ran although the pictures cannot be drawn")

    monkeypatch.setattr(importlib.util, "find_spec", find_spec)
    monkeypatch.setattr(demo, "run_circle", run_circle)
    code = main(["demo", "circle", "--steps", "4", "--no-zenoh", "--plot", str(tmp_path)])
    assert code == 1
    err = capsys.readouterr().err
    assert err == "cablebot demo: --plot needs matplotlib: pip install 'cablebot[plot]'\n"


def _circle(radius_m: float, z_m: float = 2.0) -> np.ndarray:
    return np.asarray(circle_path(radius_m, (0.0, 0.0), z_m, 12))


def test_zoom_box_around_a_small_path_with_equal_sides() -> None:
    anchors = np.asarray(load_config(None).anchors_m, dtype=np.float64)  # 80.9 m x 50 m
    assert plot.zoom_box_3d(anchors, _circle(20.0)) is None  # the paper's circle: whole robot
    box = plot.zoom_box_3d(anchors, _circle(2.0))
    assert box is not None
    lo, hi = box
    sides = hi - lo
    assert sides == pytest.approx([sides[0]] * 3)  # a cube: equal scales on x, y and z
    assert sides[0] == pytest.approx(4.0 * 1.3)
    path = _circle(2.0)
    assert np.all(path >= lo) and np.all(path <= hi)
    assert lo[2] >= 0.0  # never below the floor


@pytest.mark.parametrize("radius_m", [2.0, 20.0])
def test_plot_zooms_a_small_circle_and_shows_the_robot_in_an_inset(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, radius_m: float
) -> None:
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    figures: list[Any] = []
    real_close = plt.close

    def close(fig: Any = None) -> None:
        figures.append(fig)
        real_close(fig)

    monkeypatch.setattr(plt, "close", close)
    run = _synthetic_run(0.0)
    pts = _circle(radius_m)
    run = replace(
        run,
        spec=replace(run.spec, radius_m=radius_m),
        points_m=pts,
        setpoint_m=pts.copy(),
        fpk_m=pts.copy(),
    )
    paths = demo.plot_circle(run, tmp_path)
    assert png_size(paths[0]) == (1210, 638)
    axes = figures[0].get_axes()
    ax3d = axes[0]
    if radius_m == 2.0:
        assert len(axes) == 2  # the 3-D view and the plan-view inset
        lo, hi = plot.zoom_box_3d(run.anchors_m, np.vstack([pts, pts]))
        assert ax3d.get_xlim() == pytest.approx((lo[0], hi[0]))
        assert ax3d.get_zlim() == pytest.approx((lo[2], hi[2]))
        inset = axes[1]
        assert inset.get_title() == "plan view"
        x0, x1 = inset.get_xlim()
        assert x0 < -40.0 and x1 > 40.0  # every anchor in the inset
    else:
        assert len(axes) == 1
        x0, x1 = ax3d.get_xlim()
        assert x0 <= -40.0 and x1 >= 40.0  # the whole robot


def test_the_demo_draws_with_plot_s_figures(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import inspect

    src = inspect.getsource(demo)
    assert "import matplotlib" not in src and "plt." not in src  # one place draws: plot.py
    names = ("circle-3d.png", "circle-cable-lengths.png", "circle-fpk-xyz.png", "circle-errors.png")
    assert names == demo.PLOT_FILES  # the README's pictures keep their names
    calls: list[tuple[plot.Trace, Path, str]] = []

    def plot_trace(tr: plot.Trace, out_dir: Path, name: str) -> list[Path]:
        calls.append((tr, out_dir, name))
        return [out_dir / f"{name}-{fig}.png" for fig in plot.FIGURES]

    monkeypatch.setattr(demo, "plot_trace", plot_trace)
    run = _synthetic_run(0.25e-3)
    run = replace(run, settled_index=run.settled_index + 2)
    run = replace(
        run,
        t_s=np.concatenate([[-2.0, -1.0], run.t_s]),
        fpk_m=np.vstack([run.fpk_m[:2], run.fpk_m]),
        setpoint_m=np.vstack([run.setpoint_m[:2], run.setpoint_m]),
        residual_m=np.concatenate([[0.0, 0.0], run.residual_m]),
        valid=np.concatenate([[True, True], run.valid]),
        lengths_m=np.vstack([run.lengths_m[:2], run.lengths_m]),
        state=["DISARMED", "ARMING", *run.state],
    )  # two rows before the first settled sample (homing, arming): not drawn
    paths = demo.plot_circle(run, tmp_path)
    assert [p.name for p in paths] == list(demo.PLOT_FILES)
    ((tr, out_dir, name),) = calls
    assert out_dir == tmp_path and name == "circle"
    assert tr.t_s[0] == 0.0 and len(tr.t_s) == 13 and tr.state[0] == "HOLDING"
    assert tr.waypoints is not None
    assert np.array_equal(tr.waypoints.position_m, run.points_m)
    assert tr.waypoints.row.tolist() == list(range(13))
    assert tr.waypoints.step_label == "step (30 degrees each)"
    assert tr.setpoint_source == "every tick"
    assert np.array_equal(tr.setpoint_m, run.setpoint_m[2:])
    assert tr.shape is run.shape and tr.shape is not None
    s = demo.summarize(run)
    assert float(np.max(tr.waypoints.settled_error_m(tr.position_m))) == s.max_settled_error_m
