"""The client library's typed results read exactly what the daemon writes, and never hold a NaN:
a pose sample as `PoseSample.to_json_bytes` encodes it (any floats, the non-finite ones
included), a status or reply however odd, the simulator's truth."""

from __future__ import annotations

import json
import math
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.cli.formats import format_pose
from controller.client.model import (
    Pose,
    PretensionResult,
    Reply,
    StateChange,
    Status,
    Truth,
    pose_text,
)
from controller.service.pose import PoseSample
from controller.service.simulated import truth_payload

floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
finite = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False)


def _no_nan(value: Any) -> bool:
    """True when no float anywhere in `value` (tuples, mappings, dataclass fields) is NaN."""
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, tuple | list):
        return all(_no_nan(v) for v in value)
    if isinstance(value, dict):
        return all(_no_nan(v) for v in value.values())
    return True


@settings(deadline=None)
@given(
    seq=st.integers(min_value=0, max_value=2**53),
    pos=st.one_of(st.none(), st.tuples(floats, floats, floats)),
    lengths=st.lists(floats, min_size=3, max_size=8),
    residual=st.one_of(st.none(), floats),
    valid=st.booleans(),
    state=st.sampled_from(["HOLDING", "MOVING", "FAULT", "DISARMED"]),
    tensions=st.one_of(st.none(), st.lists(floats, min_size=3, max_size=8)),
    measured=st.one_of(st.none(), st.lists(st.one_of(st.none(), floats), min_size=3, max_size=8)),
    queued=st.integers(min_value=0, max_value=10**6),
)
def test_a_pose_reads_what_the_daemon_writes_and_never_holds_a_nan(
    seq: int,
    pos: tuple[float, float, float] | None,
    lengths: list[float],
    residual: float | None,
    valid: bool,
    state: str,
    tensions: list[float] | None,
    measured: list[float | None] | None,
    queued: int,
) -> None:
    sample = PoseSample(
        seq=seq,
        stamp_ns=1_700_000_000_000_000_000,
        position_m=pos,
        cable_lengths_m=tuple(lengths),
        residual_m=residual,
        valid=valid,
        state=state,
        tensions_n=None if tensions is None else tuple(tensions),
        measured_tensions_n=None if measured is None else tuple(measured),
        queued_points=queued,
    )
    data = sample.to_json_bytes()
    pose = Pose.from_json(data)
    assert (pose.seq, pose.state, pose.queued_points) == (seq, state, queued)
    fields = [getattr(pose, f) for f in Pose.__dataclass_fields__ if f != "raw"]
    assert _no_nan(fields)
    finite_pos = pos is not None and valid and all(math.isfinite(v) for v in pos)
    assert pose.valid == finite_pos
    if finite_pos:
        assert pose.position_m == pos
    else:
        assert pose.position_m is None and pose.residual_m is None
    assert pose.cable_lengths_m == tuple(v if math.isfinite(v) else None for v in lengths)
    assert pose.raw == data and pose.as_dict() == json.loads(data)
    if finite_pos:  # the CLI's line is the library's (an invalid pose has no residual here)
        assert pose.text() == format_pose(json.loads(data))


def test_a_pose_sample_that_is_not_one_is_refused() -> None:
    for bad in (b"[]", b"{}", b'{"seq": 1}', b'{"seq": "1", "state": "HOLDING"}', b"\xff"):
        with pytest.raises(ValueError):
            Pose.from_json(bad)
    with pytest.raises(ValueError):
        Pose.from_json(b'{"seq": 1, "state": "HOLDING", "position_m": [NaN, 0, 0]}')


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(), floats, st.text(max_size=5)),
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=12), inner, max_size=4)
    ),
    max_leaves=20,
)
status_keys = st.sampled_from(
    ["state", "reason", "pose", "setpoint_m", "homed", "axes", "path", "pretension", "config"]
)


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(status_keys, json_values, max_size=9))
def test_any_status_reply_reads_without_raising_or_a_nan(raw: dict[str, Any]) -> None:
    st_ = Status.from_mapping(raw)
    assert isinstance(st_.state, str)
    assert _no_nan([st_.position_m, st_.setpoint_m, st_.residual_m, st_.max_speed_mps])
    assert _no_nan([(a.position_rev, a.age_s) for a in st_.axes])
    assert _no_nan([st_.path.queued_s, st_.pretension.elapsed_s])
    reply = Reply.from_reply("move", raw)
    assert _no_nan([reply.target_m, reply.speed_mps, reply.tensions_n, reply.position_m])


def test_a_status_reads_its_parts() -> None:
    raw = {
        "state": "HOLDING",
        "reason": None,
        "homed": True,
        "home_source": "power_up",
        "pose": {"valid": True, "position_m": [1.0, 2.0, 3.0], "residual_m": 1e-6},
        "setpoint_m": [1.0, 2.0, 3.0],
        "axes": [
            {"node_id": 3, "ready": True, "state": "CLOSED_LOOP_CONTROL", "fault": None,
             "position_rev": 1.5, "age_s": 0.001, "heartbeat_age_s": None},
        ],
        "path": {"queued_points": 7, "queued_s": 1.25, "queue_full": False, "appendable": True},
        "pretension": {"active": False, "result": {"ok": True, "still_after_s": 2.5}},
        "config": {"name": "desk", "reels": [{"node_id": 3}], "limits": {"max_speed_mps": 0.5}},
    }  # fmt: skip
    s = Status.from_mapping(raw)
    assert (s.state, s.position_m, s.setpoint_m, s.homed) == ("HOLDING", (1.0, 2.0, 3.0),
                                                              (1.0, 2.0, 3.0), True)  # fmt: skip
    assert s.axes[0].node_id == 3 and s.axes[0].ready and s.axes[0].position_rev == 1.5
    assert (s.path.queued_points, s.path.queued_s, s.path.appendable) == (7, 1.25, True)
    assert s.pretension.result == PretensionResult.from_mapping({"ok": True, "still_after_s": 2.5})
    assert (s.robot_name, s.node_ids, s.max_speed_mps) == ("desk", (3,), 0.5)
    assert Status.from_mapping({}).state == "UNKNOWN"


def test_a_home_reply_reads_its_offsets_by_node() -> None:
    raw = {"ok": True, "position_m": [0, 0, 2], "offsets_rev": {"0": 1.5, "12": -2.0},
           "saved": True, "state_file": "/var/lib/cablebot/offsets.json"}  # fmt: skip
    r = Reply.from_reply("home", raw)
    assert r.position_m == (0.0, 0.0, 2.0) and dict(r.offsets_rev or {}) == {0: 1.5, 12: -2.0}
    assert r.saved and r.state_file == raw["state_file"] and r.raw == raw


def test_the_truth_reads_what_the_simulator_publishes() -> None:
    class Plant:
        position_m = (0.5, -0.25, 2.0)
        tensions_n = (101.0, 102.5, 99.0, 104.25)

    data = truth_payload(Plant())
    assert data is not None
    t = Truth.from_json(data)
    assert t.position_m == Plant.position_m and t.tensions_n == Plant.tensions_n


def test_a_state_change_reads_its_reason() -> None:
    c = StateChange.from_json(b'{"state": "FAULT", "reason": "stale_encoder", "stamp_ns": 5}')
    assert (c.state, c.reason, c.stamp_ns) == ("FAULT", "stale_encoder", 5)
    with pytest.raises(ValueError):
        StateChange.from_json(b'{"reason": "no state"}')


def test_the_pose_line_of_a_pose_not_valid() -> None:
    assert pose_text(7, "FAULT", None, None) == (
        "seq 7  state FAULT  x=   ---  y=   ---  z=   ---  m (pose not valid)"
    )


def test_wait_pretension_waits_for_the_daemon_to_say_the_offsets_are_saved(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The reels came to rest (HOLDING, result ok) while the offsets were still going to disk:
    # `wait_pretension` goes on asking until the daemon says they are saved, and the line the
    # CLI prints then says where (it once said "no [homing] state_file").
    from controller.cli.formats import format_pretension_result
    from controller.client import robot as robot_mod
    from controller.client.model import Status

    result = {"ok": True, "still_after_s": 3.2, "position_m": [0.3, 0.0, 2.0], "saved": False}
    replies = [
        {"state": "PRETENSIONING", "pretension": {"active": True, "result": None}},
        {
            "state": "HOLDING",
            "pretension": {"result": {**result, "saving": True, "state_file": "/x/o.json"}},
        },
        {
            "state": "HOLDING",
            "pretension": {"result": {**result, "saving": True, "state_file": "/x/o.json"}},
        },
        {
            "state": "HOLDING",
            "pretension": {"result": {**result, "saved": True, "state_file": "/x/o.json"}},
        },
    ]
    asked: list[int] = []

    def status(self: Any) -> Status:
        asked.append(1)
        return Status.from_mapping(replies[min(len(asked), len(replies)) - 1])

    monkeypatch.setattr(robot_mod.Robot, "status", status)
    monkeypatch.setattr(robot_mod, "PRETENSION_POLL_S", 0.0)
    res = robot_mod.Robot.wait_pretension(object.__new__(robot_mod.Robot), 30.0)  # type: ignore[arg-type]
    assert len(asked) == 4
    assert res.ok and not res.saving and res.raw["saved"] is True
    assert "; saved to /x/o.json" in format_pretension_result(dict(res.raw))
    # still saving when the wait for it ends: said as such, never "no state_file"
    saving = Status.from_mapping(replies[1]).pretension.result
    assert saving is not None and saving.saving
    line = format_pretension_result(dict(saving.raw))
    assert "saving to /x/o.json (not confirmed yet" in line and "no [homing]" not in line
