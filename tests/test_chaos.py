"""The chaos run (tools/chaos): its 1-minute form against both drive families, and the parts its
verdict rests on (the independent FPK, the strict JSON, the named-fault rule, the tap's checks,
the faulty link).

The run itself needs the machine's root for its namespace, tmpfs and cgroup faults; without root
those kinds are reported as not injected (a failure under CI=true, where the run is root).
"""

from __future__ import annotations

import json
import math
import os
import random
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from tests.conftest import running_under_ci

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
from chaos.checks import NAMED, Checker, strict_json  # noqa: E402
from chaos.equipment import ChaosBus, Tap, fpk  # noqa: E402
from chaos.robot import ANCHORS, robot_toml  # noqa: E402

ROOT_ONLY_KINDS = ("network_cut", "state_dir_readonly", "state_dir_full")
"""Kinds root can always inject here (iproute2, which .ci/run installs, and mount); the memory
cgroup depends on the host's cgroup set-up and is reported when it is missing."""


@settings(max_examples=60, deadline=None)
@given(
    x=st.floats(-0.45, 0.45),
    y=st.floats(-0.45, 0.45),
    z=st.floats(0.02, 0.7),
)
def test_fpk_matches_scipy_and_the_true_point(x: float, y: float, z: float) -> None:
    anchors = np.array(ANCHORS)
    p = np.array([x, y, z])
    lengths = np.linalg.norm(anchors - p, axis=1)
    got, misfit = fpk(anchors, lengths, np.array([0.0, 0.0, 0.3]))
    ref = least_squares(
        lambda q: np.linalg.norm(anchors - q, axis=1) - lengths, x0=[0.0, 0.0, 0.3], xtol=1e-14
    ).x
    assert np.linalg.norm(got - p) < 1e-6 and misfit < 1e-9
    assert np.linalg.norm(got - ref) < 1e-6


def test_strict_json_refuses_nan_and_infinity() -> None:
    assert strict_json(b'{"a": [1.5, 2]}') == {"a": [1.5, 2]}
    for bad in (b'{"a": NaN}', b"[Infinity]", b"[-Infinity]"):
        with pytest.raises(ValueError, match="non-finite"):
            strict_json(bad)


def test_a_fault_is_named_by_its_kind() -> None:
    for ok in ("estop", "stale_encoder: node 3 age 0.3 s", "bus_conflict: another SYNC producer"):
        assert NAMED.match(ok)
    for bad in ("", "Restarted", "stale encoder", ": nothing", "kind:"):
        assert not NAMED.match(bad)
    c = Checker(np.array(ANCHORS), 0.02)
    c.state_sample(b'{"state": "FAULT", "reason": "axis_error: node 1 unknown", "stamp_ns": 1}')
    c.state_sample(b'{"state": "FAULT", "reason": null, "stamp_ns": 2}')
    c.state_sample(b'{"state": "ESTOPPED", "reason": "estop", "stamp_ns": 3}')
    assert [v.kind for v in c.violations] == ["unnamed_fault", "unnamed_fault"]


def test_pose_sequence_gaps_outside_stalls_are_counted() -> None:
    c = Checker(np.array(ANCHORS), 0.02)
    for seq in (1, 2, 5):  # two missing
        c.pose_sample(json.dumps({"seq": seq, "state": "HOLDING", "valid": True}).encode())
    now = time.monotonic()
    c.stall(now, now + 0.1)
    c.pose_sample(json.dumps({"seq": 9, "state": "HOLDING", "valid": True}).encode())
    c.pose_sample(json.dumps({"seq": 1, "state": "DISARMED", "valid": True}).encode())  # restart
    assert (c.seq_lost, c.seq_lost_in_stalls, c.seq_restarts) == (2, 3, 1)
    c.pose_sample(b'{"seq": 2, "position_m": [NaN, 0, 0]}')
    assert [v.kind for v in c.violations] == ["nan_on_zenoh"]


def _cfg(tmp_path: Path, family: str) -> Any:
    from controller.service.config import load_config

    path = tmp_path / "robot.toml"
    text = robot_toml(family, "t", tmp_path, ["tcp/127.0.0.1:7447"], random.Random(1))
    path.write_text(text)
    return load_config(str(path))


class _Msg:
    def __init__(self, arb: int, data: bytes, stamp: float) -> None:
        self.arbitration_id, self.data, self.timestamp = arb, data, stamp
        self.is_error_frame = self.is_extended_id = self.is_remote_frame = False


def _odrive_setpoint(node: int, turns: float, stamp: float) -> _Msg:
    import struct

    return _Msg(node << 5 | 0x0C, struct.pack("<fhh", turns, 0, 0), stamp)


def test_tap_flags_a_nan_command_and_a_cable_faster_than_the_limit(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, "odrive")
    found: list[tuple[str, str]] = []
    tap = Tap(None, "odrive", cfg, lambda i: 0.0, lambda k, t: found.append((k, t)))  # type: ignore[arg-type]
    reel = cfg.reels[0].reel
    vmax = float(cfg.limits.max_cable_speed_mps)
    t = 1000.0
    for k in range(60):  # 0.6 s at 90 % of the cable speed limit: fine
        m = _odrive_setpoint(0, reel.position_rev(0.8 + 0.9 * vmax * 0.01 * k), t + 0.01 * k)
        tap._odrive(m.arbitration_id, m.data, m.timestamp, False)
    assert found == []
    for k in range(60, 120):  # then at twice the limit
        length = 0.8 + 0.9 * vmax * 0.6 + 2.0 * vmax * 0.01 * (k - 60)
        m = _odrive_setpoint(0, reel.position_rev(length), t + 0.01 * k)
        tap._odrive(m.arbitration_id, m.data, m.timestamp, False)
    assert [k for k, _ in found][:1] == ["cable_too_fast"]
    m = _odrive_setpoint(1, math.nan, t + 2.0)
    tap._odrive(m.arbitration_id, m.data, m.timestamp, False)
    assert found[-1][0] == "nan_on_bus"
    m = _odrive_setpoint(2, reel.position_rev(5.0), t + 2.0)  # a 5 m cable: past the limit
    tap._odrive(m.arbitration_id, m.data, m.timestamp, False)
    assert found[-1][0] == "setpoint_outside_workspace"


class _FakeBus:
    def __init__(self) -> None:
        self.sent: list[can.Message] = []
        self.inbox = [can.Message(arbitration_id=i, data=b"\x01\x02") for i in range(1000)]

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return self.inbox.pop(0) if self.inbox else None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(msg)

    def shutdown(self) -> None:
        pass


def test_chaos_bus_loses_cuts_short_and_duplicates() -> None:
    fake = _FakeBus()
    bus = ChaosBus(fake, random.Random(7))  # type: ignore[arg-type]
    bus.loss = 0.1
    got = 0
    while bus.recv(0.0) is not None:
        got += 1
    assert 850 < got < 950 and bus.lost == 1000 - got
    bus.loss = 0.0
    bus.corrupt_left, bus.duplicate_left = 2, 3
    for i in range(5):
        bus.send(can.Message(arbitration_id=0x100 + i, data=bytes(8)))
    assert [len(m.data) < 8 for m in fake.sent][:2] == [True, True]
    assert len(fake.sent) == 8 and bus.duplicated == 3 and bus.corrupted == 2
    bus.blackout_until_s = time.monotonic() + 10.0
    bus.send(can.Message(arbitration_id=0x1, data=b""))
    assert len(fake.sent) == 8


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_one_minute_chaos_run_keeps_every_invariant(tmp_path: Path) -> None:
    out = tmp_path / "report.json"
    env = dict(os.environ, PYTHONPATH=f"{ROOT / 'tools'}{os.pathsep}{ROOT}")
    proc = subprocess.run(
        [sys.executable, "-m", "chaos", "--duration-s", "60", "--json", str(out),
         "--workdir", str(tmp_path / "work")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=800,
    )  # fmt: skip
    summary = json.loads(out.read_text()) if out.exists() else {}
    assert proc.returncode == 0, proc.stdout[-6000:] + proc.stderr[-3000:]
    workers = {w["family"]: w for w in summary["workers"]}
    assert sorted(workers) == ["cia402", "odrive"] and not summary["failed"]
    for fam, w in workers.items():
        injected = sum(k["injected"] for k in w["faults"].values())
        assert injected >= 6, (fam, w["faults"])
        assert not w["violations"], (fam, w["violations"])
        assert w["tracking_checks"] > 100 and w["tap"]["setpoints"] > 1000, (fam, w["tap"])
        if running_under_ci() or os.geteuid() == 0:
            assert not set(w["unavailable"]) & set(ROOT_ONLY_KINDS), w["unavailable"]
