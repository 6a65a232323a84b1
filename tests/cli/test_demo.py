"""`cablebot demo circle`: the recorder, the numbers, and the demo itself as a real process.

The end-to-end test runs the short form (12 steps on a 1 m circle, at the paper robot's
anchors and reels) as `python -m controller.cli demo circle ...` in its own process: the
control loop, the ODrive driver, simulated ODrive nodes on a python-can virtual bus and Zenoh
on a free port. It checks the four PNG files and the printed figures (settled FPK error within
1 mm, encoder lengths within the reel resolution of pure IPK).
"""

from __future__ import annotations

import math
import re
import struct
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller.cli import demo
from controller.cli.shape import RobotShape
from controller.core.kinematics import Geometry, ipk
from controller.service.config import load_config, paper_robot_data
from controller.service.pose import PoseSample
from tests.daemon_procs import to_toml

REPO = Path(__file__).resolve().parents[2]
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


# --------------------------------------------------------------------------------- helpers


def write_toml(data: dict[str, Any], path: Path) -> None:
    """Write a robot mapping as TOML (the cross-process tests' writer)."""
    path.write_text(to_toml(data))


def png_size(path: Path) -> tuple[int, int]:
    """Width and height from the PNG's IHDR chunk (asserts the signature)."""
    head = path.read_bytes()[:24]
    assert head[:8] == PNG_SIGNATURE, f"{path} is not a PNG"
    assert head[12:16] == b"IHDR"
    w, h = struct.unpack(">II", head[16:24])
    return int(w), int(h)


class _Ctl:
    setpoint_m: tuple[float, float, float] | None = None


class _Sink:
    def __init__(self) -> None:
        self.poses: list[PoseSample] = []
        self.states: list[str] = []

    def publish_pose(self, sample: PoseSample) -> None:
        self.poses.append(sample)

    def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
        self.states.append(state)


def _sample(seq: int, pos: tuple[float, float, float] | None, state: str) -> PoseSample:
    return PoseSample(
        seq=seq,
        stamp_ns=seq,
        position_m=pos,
        cable_lengths_m=(1.0 + seq, 2.0, 3.0, 4.0),
        residual_m=None if pos is None else 1e-6 * seq,
        valid=pos is not None,
        state=state,
    )


# --------------------------------------------------------------------------------- unit tests


def test_recorder_records_rows_forwards_and_drops_past_capacity() -> None:
    ctl = _Ctl()
    sink = _Sink()
    clock = iter([10.0, 10.002, 10.004, 10.006])
    rec = demo.Recorder(ctl, 4, capacity=3, inner=sink, clock=lambda: next(clock))
    rec.publish_pose(_sample(1, None, "DISARMED"))
    ctl.setpoint_m = (1.0, 2.0, 3.0)
    rec.publish_pose(_sample(2, (1.5, 2.5, 3.5), "MOVING"))
    rec.publish_pose(_sample(3, (1.0, 2.0, 3.0), "HOLDING"))
    rec.publish_pose(_sample(4, (1.0, 2.0, 3.0), "HOLDING"))  # past capacity
    rec.publish_state("HOLDING", None, 5)
    assert rec.count == 3 and rec.dropped == 1
    assert len(sink.poses) == 4 and sink.states == ["HOLDING"]
    rows = rec.rows()
    assert rows.shape == (3, 14)
    assert rows[0, 0] == 10.0 and rows[2, 0] == 10.004
    assert np.isnan(rows[0, 1:8]).all() and rows[0, 8] == 0.0  # no set-point, no pose
    assert rows[1, 1:4].tolist() == [1.0, 2.0, 3.0]
    assert rows[1, 4:7].tolist() == [1.5, 2.5, 3.5]
    assert rows[1, 7] == pytest.approx(2e-6) and rows[1, 8] == 1.0
    assert [int(c) for c in rows[:, 9]] == [0, 3, 2]  # DISARMED, MOVING, HOLDING
    assert rows[2, 10:].tolist() == [4.0, 2.0, 3.0, 4.0]
    assert rec.last_time_s() == 10.004
    assert np.array_equal(rec.rows(1), rows[1:], equal_nan=True)
    assert rec.rows(3).shape == (0, 14) and rec.rows(99).shape == (0, 14)


def test_recorder_survives_a_failing_inner_publisher() -> None:
    class Broken:
        def publish_pose(self, sample: PoseSample) -> None:
            raise RuntimeError("network down")

        def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
            raise RuntimeError("network down")

    rec = demo.Recorder(_Ctl(), 4, capacity=4, inner=Broken())
    rec.publish_pose(_sample(1, (0.0, 0.0, 1.0), "HOLDING"))
    rec.publish_state("HOLDING", None, 1)
    assert rec.count == 1 and rec.inner_errors == 2


def _synthetic_run(error_m: float) -> demo.CircleRun:
    """A perfect lap of the paper circle (12 steps) with a known error at one settled point."""
    from controller.core.motion import circle_path

    cfg = load_config(None)
    geom = Geometry(cfg.anchors_m)
    spec = demo.CircleSpec(steps=12)
    pts = np.asarray(circle_path(spec.radius_m, spec.centre_m, spec.z_m, spec.steps))
    fpk = pts.copy()
    fpk[5, 2] += error_m
    lengths = np.asarray(ipk(geom, pts))
    n = len(pts)
    return demo.CircleRun(
        robot="default",
        spec=spec,
        speed_mps=1.0,
        rate_hz=500.0,
        anchors_m=np.asarray(cfg.anchors_m, dtype=np.float64),
        points_m=pts,
        t_s=np.arange(n, dtype=np.float64),
        setpoint_m=pts.copy(),
        fpk_m=fpk,
        residual_m=np.zeros(n),
        valid=np.ones(n, dtype=bool),
        state=["HOLDING"] * n,
        lengths_m=lengths,
        settled_index=np.arange(n, dtype=np.int64),
        turns_max_abs_rev=np.full(4, 1200.0),
        reel_slope_m_per_rev=np.full(4, 0.05),
        zenoh="off",
        wall_s=1.0,
        overruns=0,
        ticks=n,
        dropped_rows=0,
        shape=RobotShape.from_summary(cfg.summary()),
    )


def test_summary_numbers_and_final_line() -> None:
    run = _synthetic_run(0.25e-3)
    s = demo.summarize(run)
    assert s.points == 12
    assert s.max_settled_error_m == pytest.approx(0.25e-3, rel=1e-9)
    assert s.rms_settled_error_m == pytest.approx(0.25e-3 / math.sqrt(12), rel=1e-9)
    assert s.ipk_cmd_max_diff_m < 1e-12
    # one float32 step at 1200 turns is 2^-13 turn = 6.1 micrometres at 0.05 m per turn
    assert s.resolution_m == pytest.approx(2.0**-13 * 0.05)
    assert s.length_min_m[0] == pytest.approx(float(run.lengths_m[:, 0].min()))
    lines = demo.format_summary(run, s, 1e-3)
    assert lines[-1] == (
        "max settled FPK error: 0.2500 mm (12 points; agrees with the commanded circle within 1 mm)"
    )
    bad = demo.format_summary(run, demo.summarize(_synthetic_run(2e-3)), 1e-3)
    assert "DISAGREES" in bad[-1]


def test_plot_needs_matplotlib(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(ImportError):
        demo.plot_circle(_synthetic_run(0.0), tmp_path)
    assert not list(tmp_path.iterdir())


def test_demo_config_is_virtual_sim_without_state_file() -> None:
    cfg = load_config(REPO / "config" / "paper-acre.toml")
    d = demo.demo_config(cfg, channel="chan-x", zenoh_listen="tcp/127.0.0.1:40001")
    assert d.bus.interface == "virtual" and d.bus.channel == "chan-x"
    assert d.sim.enabled and d.homing.state_file is None
    assert d.homing.power_up_position_m is None
    assert d.zenoh.listen == ("tcp/127.0.0.1:40001",) and d.zenoh.connect == ()
    assert d.faults.stale_timeout_s == 1.0 and d.faults.tracking_max_m == 1.0
    assert d.geometry is cfg.geometry and d.reels == cfg.reels
    assert cfg.sim.watchdog_timeout_s == pytest.approx(0.3)
    assert d.sim.watchdog_timeout_s == demo.DEMO_SIM_WATCHDOG_FLOOR_S == 2.0
    strict = demo.demo_config(cfg, channel="c", zenoh_listen=None, strict_faults=True)
    assert strict.faults == cfg.faults and strict.zenoh.listen == ()
    assert strict.sim.watchdog_timeout_s == cfg.sim.watchdog_timeout_s
    off = replace(cfg, sim=replace(cfg.sim, watchdog_timeout_s=0.0))
    assert demo.demo_config(off, channel="c", zenoh_listen=None).sim.watchdog_timeout_s == 0.0


def test_circle_outside_the_limits_is_refused_before_anything_starts() -> None:
    with pytest.raises(ValueError, match=r"path point 3: .* outside the anchors' plan-view"):
        demo.run_circle(load_config(None), demo.CircleSpec(radius_m=30.0, steps=8))
    with pytest.raises(ValueError, match="max_speed_mps"):
        demo.run_circle(load_config(None), demo.CircleSpec(speed_mps=5.0))


def test_estimated_duration_matches_trapezoids() -> None:
    # 2 m legs at 1 m/s and 1 m/s^2: 1 s up, 1 s cruise, 1 s down each.
    pts = [(0.0, 0.0, 2.0), (2.0, 0.0, 2.0), (2.0, 2.0, 2.0)]
    assert demo.estimate_duration_s(pts, 1.0, 1.0) == pytest.approx(6.0)


# --------------------------------------------------------------------------------- end to end


@pytest.mark.slow
@pytest.mark.timeout(150)
def test_demo_circle_short_form_runs_and_draws(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    data = paper_robot_data("demo-test")
    # Quicker legs than the paper robot's 1 m/s^2 so the lap takes ~10 s.
    data["limits"]["max_accel_mps2"] = 4.0
    cfg_path = tmp_path / "robot.toml"
    write_toml(data, cfg_path)
    load_config(cfg_path)  # the file is valid
    img = tmp_path / "img"
    cmd = [
        sys.executable,
        "-m",
        "controller.cli",
        "demo",
        "circle",
        "--config",
        str(cfg_path),
        "--steps",
        "12",
        "--radius",
        "1",
        "--speed",
        "1",
        "--plot",
        str(img),
    ]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=140, check=False)
    out = proc.stdout
    assert proc.returncode == 0, f"exit {proc.returncode}\n{out}\n{proc.stderr}"

    for name in demo.PLOT_FILES:
        p = img / name
        assert p.is_file(), f"{name} missing\n{out}"
        size = p.stat().st_size
        assert 20_000 < size < 3_000_000, f"{name}: {size} bytes"
        w, h = png_size(p)
        assert 600 <= w <= 3000 and 400 <= h <= 3000, f"{name}: {w}x{h}"

    last = out.strip().splitlines()[-1]
    m = re.fullmatch(r"max settled FPK error: ([0-9.]+) mm \((\d+) points; agrees .*\)", last)
    assert m, f"last line: {last!r}\n{out}"
    assert int(m.group(2)) == 12
    assert float(m.group(1)) <= 1.0
    m = re.search(
        r"encoder lengths vs pure IPK of the commanded points: max ([0-9.]+) mm "
        r"\(within the reel resolution\)",
        out,
    )
    assert m, out
    res = re.search(r"one float32 step of motor turns = ([0-9.]+) mm", out)
    assert res, out
    assert float(m.group(1)) <= float(res.group(1))
    ranges = re.findall(r"cable (\d): +([0-9.]+) \.\. +([0-9.]+) m", out)
    assert [int(c) for c, _, _ in ranges] == [1, 2, 3, 4]
    for _, lo, hi in ranges:  # 1 m circle at z = 2 m about the centre: about 47.4..48.4 m
        assert 46.0 < float(lo) < float(hi) < 50.0
