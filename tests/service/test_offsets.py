"""Homing state file: atomic save, load, record checks, and the SIGKILL test."""

from __future__ import annotations

import json
import os
import random
import select
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from controller.service.offsets import (
    HomingError,
    load_offsets,
    make_record,
    parse_record,
    restored_pose_problem,
    save_offsets,
)

REPO = Path(__file__).resolve().parents[2]
HELPER = Path(__file__).resolve().parents[1] / "homing_kill_helper.py"
sys.path.insert(0, str(HELPER.parent))
from homing_kill_helper import version  # noqa: E402


def test_save_load_round_trip_and_replace(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "robot.json"  # parent created on demand
    assert load_offsets(path) is None
    rec = make_record("desk", {0: 1.25, 3: -7.5}, (0.0, 0.1, 0.4), wall_time_s=123.5)
    save_offsets(path, rec)
    assert load_offsets(path) == rec
    parsed = parse_record(rec, str(path), robot="desk", node_ids=[3, 0])
    assert parsed.offsets_rev == {0: 1.25, 3: -7.5}
    assert parsed.home_position_m == (0.0, 0.1, 0.4)
    assert parsed.wall_time_s == 123.5
    rec2 = make_record("desk", {0: 2.0, 3: 3.0}, (0.0, 0.0, 0.5), wall_time_s=200.0)
    save_offsets(path, rec2)
    assert load_offsets(path) == rec2
    assert sorted(p.name for p in path.parent.iterdir()) == ["robot.json"]  # no temp left


def test_unserialisable_or_nan_writes_nothing(tmp_path: Path) -> None:
    path = tmp_path / "s.json"
    save_offsets(path, {"a": 1})
    with pytest.raises(ValueError):
        save_offsets(path, {"a": float("nan")})
    with pytest.raises(TypeError):
        save_offsets(path, {"a": object()})
    assert load_offsets(path) == {"a": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]
    with pytest.raises(ValueError, match="finite"):
        make_record("x", {0: float("inf")}, (0, 0, 0))


def test_broken_file_raises_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "broken.json"
    path.write_text('{"format": 1, "robot": "de')
    with pytest.raises(HomingError, match=r"broken\.json.*not valid JSON"):
        load_offsets(path)
    path.write_text("[1, 2]")
    with pytest.raises(HomingError, match="JSON object"):
        load_offsets(path)


def test_stale_temp_files_are_cleaned(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    stale = tmp_path / ".r.json.abc123.tmp"
    fresh = tmp_path / ".r.json.def456.tmp"
    stale.write_text("x")
    fresh.write_text("y")
    old = time.time() - 3600
    os.utime(stale, (old, old))
    save_offsets(path, {"a": 1})
    assert not stale.exists()
    assert fresh.exists()  # could belong to a concurrent writer


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"format": 2}, "unsupported format"),
        ({"robot": "other"}, "for robot 'other', not 'desk'"),
        ({"offsets_rev": {"0": 1.0}}, r"holds nodes \[0\], this robot has \[0, 1\]"),
        ({"offsets_rev": {"0": 1.0, "x": 2.0}}, "not a node id"),
        ({"offsets_rev": {"0": 1.0, "1": "2"}}, r"offsets_rev\[1\] must be a finite number"),
        ({"home_position_m": [0, 0]}, "home_position_m"),
        ({"wall_time_s": None}, "wall_time_s"),
    ],
)
def test_parse_record_rejects(change: dict[str, Any], message: str) -> None:
    rec = make_record("desk", {0: 1.0, 1: 2.0}, (0, 0, 0.3))
    rec.update(change)
    with pytest.raises(HomingError, match=message):
        parse_record(rec, "state.json", robot="desk", node_ids=[0, 1])


def _run_kill_trial(
    path: Path, first_seq: int, rng: random.Random, unsafe: bool = False
) -> tuple[int, int]:
    """Start the helper, wait for its first save, SIGKILL it at a random moment.

    Returns (seq found in the file afterwards, number of temporary files left behind).
    """
    env = dict(os.environ, PYTHONPATH=str(REPO))
    args = [sys.executable, str(HELPER), str(path), str(first_seq)]
    if unsafe:
        args.append("--unsafe")
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, cwd=REPO, env=env)
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + 60.0
        ready = b""
        while b"ready" not in ready:
            remaining = deadline - time.monotonic()
            assert remaining > 0, "helper did not report its first save within 60 s"
            r, _, _ = select.select([proc.stdout], [], [], remaining)
            if r:
                chunk = os.read(proc.stdout.fileno(), 64)
                assert chunk, f"helper exited early with {proc.wait(5)}"
                ready += chunk
        time.sleep(rng.uniform(0.0, 0.08))  # the random moment (the helper saves meanwhile)
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=30) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)
        if proc.stdout is not None:
            proc.stdout.close()
    temps = list(path.parent.glob(f".{path.name}.*.tmp"))
    for t in temps:
        t.unlink()
    data = load_offsets(path)  # raises HomingError on a torn file
    assert data is not None
    assert data == version(data["seq"]), "file parses but is not one written version"
    return int(data["seq"]), len(temps)


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_sigkill_during_save_leaves_old_or_new_file(tmp_path: Path) -> None:
    """SIGKILL a process saving in a tight loop, 30 times: the file is always a whole version."""
    path = tmp_path / "kill.json"
    save_offsets(path, version(0))
    rng = random.Random(1234)
    seq = 0
    mid_write = 0
    saves = 0
    for _ in range(30):
        found, temps = _run_kill_trial(path, seq + 1, rng)
        assert found >= seq  # never goes back to an older version than the last one seen
        saves += found - seq
        seq = found
        mid_write += temps
    print(f"30 kills, {saves} saves completed, {mid_write} kills left a temporary file behind")
    assert seq > 30  # the helper really saved many versions


def test_torn_file_detection_works(tmp_path: Path) -> None:
    """The check used by the kill test does catch a torn file (written in place)."""
    path = tmp_path / "kill.json"
    good = json.dumps(version(3), indent=1, sort_keys=True)
    path.write_text(good[: len(good) // 2])
    with pytest.raises(HomingError):
        load_offsets(path)


def _floor_rule(p: Any) -> str | None:
    return f"z={p[2]:.4g} m below the floor (0 m)" if p[2] < 0.0 else None


def test_a_restored_pose_below_the_floor_is_named_with_how_to_home_again() -> None:
    text = restored_pose_problem([0.0, 0.0, -1.3087], _floor_rule, [0.0, 0.0, 2.0], 1.0, "s.json")
    assert text is not None
    assert text.startswith(
        "the homing offsets from s.json put the effector at [0.0000, 0.0000, -1.3087] m, "
        "outside the workspace (z=-1.309 m below the floor (0 m)) and 3.309 m from the "
        "power-up pose [0.0000, 0.0000, 2.0000]: they are stale if a drive restarted"
    )
    assert "run `cablebot home X Y Z`; or remove s.json and restart" in text
    # without a power-up pose: the workspace alone, and no "remove" advice
    text = restored_pose_problem([0.0, 0.0, -1.3087], _floor_rule, None, 1.0, "s.json")
    assert text is not None and "power-up" not in text and text.endswith("`cablebot home X Y Z`")


def test_a_restored_pose_inside_and_near_the_power_up_pose_is_believed() -> None:
    assert restored_pose_problem([0.0, 0.1, 2.0], _floor_rule, [0.0, 0.0, 2.0], 0.5, "s") is None
    assert restored_pose_problem([9.0, 0.0, 2.0], _floor_rule, None, 0.5, "s") is None
    far = restored_pose_problem([0.0, 0.6, 2.0], _floor_rule, [0.0, 0.0, 2.0], 0.5, "s")
    assert far is not None and "0.600 m from the power-up pose" in far
    assert "outside" not in far


def test_offsets_that_give_no_pose_are_named() -> None:
    text = restored_pose_problem(None, _floor_rule, [0.0, 0.0, 2.0], 0.5, "s.json")
    assert text is not None
    assert text.startswith(
        "the homing offsets from s.json give no valid pose with the drives' readings: they "
        "are stale"
    )
