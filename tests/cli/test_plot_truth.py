"""`cablebot plot` and the simulator's truth: the errors of the effector against the set-point
and of the published pose against the truth, read from a recording, drawn for several."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from controller.cli import plot_truth
from controller.cli.record import McapRecorder

pytest.importorskip("matplotlib")

PREFIX = "cablebot/x"


def write_recording(path: Path, offset_m: float, pose_off_m: float, truth: bool = True) -> None:
    """A straight move along x at 1 m/s for 2 s: the set-point on the line, the truth
    `offset_m` beside it in y, the published pose `pose_off_m` above the truth in z; truth and
    poses at 100 Hz, status at 10 Hz (times in ns)."""
    with open(path, "wb") as f:
        rec = McapRecorder(f, PREFIX)
        for k in range(201):
            t_ns = 1_000_000_000 + k * 10_000_000
            x = 0.01 * k
            if truth:
                payload = {"position_m": [x, offset_m, 2.0], "tensions_n": [100.0] * 4}
                rec.add(f"{PREFIX}/sim/truth", json.dumps(payload).encode(), t_ns)
            pose = {
                "seq": k,
                "stamp_ns": t_ns,
                "position_m": [x, offset_m, 2.0 + pose_off_m],
                "cable_lengths_m": [1.0] * 4,
                "residual_m": 0.0,
                "valid": k > 0,
                "state": "MOVING",
            }
            rec.add(f"{PREFIX}/pose", json.dumps(pose).encode(), t_ns + 1)
            if k % 10 == 5:
                status = {"setpoint_m": [x, 0.0, 2.0], "pose": pose}
                rec.add(f"{PREFIX}/status", json.dumps(status).encode(), t_ns + 2)
        rec.close()


def test_truth_errors_read_the_offsets(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    write_recording(path, 0.04, 0.002)
    assert plot_truth.has_truth(path)
    e = plot_truth.truth_errors(path, label="rigid")
    assert e.label == "rigid"
    assert len(e.status_t_s) == 20 and len(e.pose_t_s) == 201
    assert np.allclose(e.target_err_m, 0.04, atol=1e-6)
    assert math.isnan(e.pose_err_m[0])  # not valid yet
    assert np.allclose(e.pose_err_m[1:-1], 0.002, atol=1e-6)
    assert math.isnan(e.pose_err_m[-1])  # after the last truth: none


def test_a_recording_without_truth(tmp_path: Path) -> None:
    path = tmp_path / "plain.mcap"
    write_recording(path, 0.0, 0.0, truth=False)
    assert not plot_truth.has_truth(path)
    with pytest.raises(plot_truth.TruthError, match="no simulator truth"):
        plot_truth.truth_errors(path)


def test_cablebot_plot_draws_the_truth_of_two_recordings(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from controller.cli import main

    rigid, stretch = tmp_path / "rigid.mcap", tmp_path / "stretch.mcap"
    write_recording(rigid, 0.04, 0.04)
    write_recording(stretch, 1e-5, 1e-5)
    out = tmp_path / "figs"
    rc = main(
        ["plot", str(stretch), "--out", str(out), "--prefix", PREFIX, "--compare", str(rigid)]
    )
    assert rc == 0
    assert (out / "stretch-truth.png").stat().st_size > 10_000
    assert "stretch-truth.png" in capsys.readouterr().out
    # a recording without truth: no truth figure, and --compare needs one
    plain = tmp_path / "plain.mcap"
    write_recording(plain, 0.0, 0.0, truth=False)
    assert main(["plot", str(plain), "--out", str(out), "--prefix", PREFIX]) == 0
    assert not (out / "plain-truth.png").exists()
    args = ["plot", str(plain), "--out", str(out), "--prefix", PREFIX, "--compare", str(rigid)]
    assert main(args) == 1
