"""Anchor calibration of a robot among its anchors (a Hangprinter): the poses are not kept below
the anchors (they are above the low ones), and the gate asks that they stay inside the anchors'
hull instead. Synthetic samples on config/hangprinter-v4.toml, as in test_calibration.py: the
true anchors displaced 3-10 cm, 25 poses spread over the pyramid, 0.1 mm of length noise,
unknown reel offsets, the believed poses the daemon's FPK of the configured anchors.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from controller.core import calibration as cal
from controller.core import kinematics
from controller.core.workspace import Workspace
from controller.service.config import load_config
from tests.core.test_calibration import N_POSES, NOISE_M, Rig, aligned_truth, anchor_errors_m

HP4 = Path(__file__).resolve().parents[2] / "config" / "hangprinter-v4.toml"


def hangprinter_rig(seed: int) -> Rig:
    cfg = load_config(HP4)
    rng = np.random.default_rng(seed)
    a_cfg = np.array(cfg.anchors_m, dtype=float)
    d = rng.normal(size=a_cfg.shape)
    d /= np.linalg.norm(d, axis=1)[:, None]
    a_true = a_cfg + d * rng.uniform(0.03, 0.10, size=(len(a_cfg), 1))
    reels = [r.reel for r in cfg.reels]
    true_reels = [
        replace(r, offset_rev=float(o))
        for r, o in zip(reels, rng.uniform(-20, 20, len(reels)), strict=True)
    ]
    limits = Workspace.from_limits(cfg.limits, cfg.geometry)
    assert not limits.hanging
    return Rig(a_cfg, a_true, reels, true_reels, cfg.node_ids, limits, rng)


def samples_of(rig: Rig) -> cal.Samples:
    poses = rig.poses(N_POSES, margin_m=0.03)
    turns = rig.turns(poses)
    geom = kinematics.Geometry(rig.config_anchors_m, hanging=False)
    home = kinematics.ipk_point(geom, tuple(poses[0]))
    homed = [r.with_home(float(t), h) for r, t, h in zip(rig.reels, turns[0], home, strict=True)]
    believed = [
        kinematics.fpk(
            geom, [r.length_m(float(t)) for r, t in zip(homed, row, strict=True)]
        ).position_m
        for row in turns
    ]
    return cal.Samples(rig.node_ids, turns, np.array(believed))


@pytest.mark.parametrize("seed", [0, 1])
def test_hangprinter_v4_recovers_its_anchors(seed: int) -> None:
    rig = hangprinter_rig(seed)
    samples = samples_of(rig)
    # above the low anchors: the hanging solve refuses such samples outright
    with pytest.raises(cal.CalibrationError, match="at or above the lowest anchor"):
        cal.calibrate(rig.config_anchors_m, rig.reels, samples)
    res = cal.calibrate(rig.config_anchors_m, rig.reels, samples, hanging=False)
    truth = aligned_truth(rig)
    before = anchor_errors_m(rig.config_anchors_m, truth)
    after = anchor_errors_m(res.anchors_m, truth)
    assert before.max() > 0.03
    assert after.max() < 3e-3, (before, after, res.warnings)
    assert res.ok, res.gates
    assert [g.name for g in res.gates][-1] == "inside_hull"
    assert not res.anchors_coplanar and not res.held
    assert res.rms_m < 2 * NOISE_M
