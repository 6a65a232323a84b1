"""`cablebot calibrate solve` offline, and `cablebot calibrate collect` against a real daemon.

The solve tests run the CLI in-process on synthetic samples (tests/test_calibration.py's rigs).
The collect tests start a daemon with simulated ODrives (a desk-sized rig on its own
udp_multicast port, hop_limit 0, Zenoh on a free loopback port), record samples with
`--auto` and by Enter on stdin, and solve them.
"""

from __future__ import annotations

import csv
import io
import json
import random
import re
import subprocess
import time
import tomllib
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller.cli import exitcodes, main
from controller.core import calibration as cal
from controller.service.config import load_config
from controller.service.offsets import load_offsets, parse_record
from tests.core.test_calibration import DESK, aligned_truth, make_rig, sample_set
from tests.daemon_procs import CABLEBOT, REPO, Proc, free_tcp_port, to_toml, zenoh_session, zquery


def hangprinter_desk_config(tmp_path: Path) -> Path:
    """config/desk.toml with anchors 2 and 4 raised by 0.2 m (a text edit: comments kept)."""
    text = DESK.read_text()
    for old in ("[-0.5, 0.5, 0.8]", "[0.5, -0.5, 0.8]"):
        assert old in text
        text = text.replace(old, old.replace("0.8]", "1.0]"))
    path = tmp_path / "desk-hp.toml"
    path.write_text(text)
    return path


def write_samples(path: Path, samples: cal.Samples) -> None:
    with path.open("w", newline="") as fh:
        fh.write(cal.samples_preamble("desk", samples.node_ids, "test"))
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(cal.samples_header(samples.node_ids))
        for rev, pose in zip(samples.motor_rev, samples.believed_m, strict=True):
            w.writerow(cal.format_sample_row(rev, pose))


def run_cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


# --------------------------------------------------------------------------------------------
# solve (offline)


def test_solve_json_and_write_keep_the_rest_of_the_config(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg_path = hangprinter_desk_config(tmp_path)
    rig = make_rig(DESK, seed=0, raise_diagonal_m=0.2)
    assert np.allclose(rig.config_anchors_m, load_config(cfg_path).anchors_m)
    samples, _ = sample_set(rig)
    csv_path = tmp_path / "s.csv"
    write_samples(csv_path, samples)
    new_path = tmp_path / "new.toml"
    state_path = tmp_path / "offsets.json"

    code, out, err = run_cli(
        [
            "calibrate",
            "solve",
            str(csv_path),
            "--config",
            str(cfg_path),
            "--json",
            "--write",
            str(new_path),
            "--write-offsets",
            str(state_path),
        ],
        capsys,
    )
    assert code == 0, err
    data = json.loads(out)
    assert data["ok"] is True
    anchors = np.array(data["anchors_m"])
    assert anchors.shape == (4, 3)
    assert np.linalg.norm(anchors - aligned_truth(rig), axis=1).max() < 2e-3
    assert 0.0 < data["rms_residual_m"] < 2e-4
    assert data["written"] == {"config": str(new_path), "offsets": str(state_path)}

    # The new file: the old text but the four anchor lines; it loads with the new anchors.
    old_lines = cfg_path.read_text().splitlines()
    new_lines = new_path.read_text().splitlines()
    changed = [b for a, b in zip(old_lines, new_lines, strict=True) if a != b]
    assert len(changed) == 4 and all(c.startswith("anchor_m = [") for c in changed)
    assert "# ODrive + 30 mm diameter drum" in new_path.read_text()
    assert np.allclose(load_config(new_path).anchors_m, anchors, atol=1e-6)
    # The offsets: a homing record the daemon accepts for this robot.
    rec = parse_record(load_offsets(state_path) or {}, "offsets", "desk", (0, 1, 2, 3))
    assert np.allclose([rec.offsets_rev[i] for i in range(4)], data["offsets_rev"])


def test_solve_report_names_held_directions_and_passes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = make_rig(DESK, seed=0)
    samples, _ = sample_set(rig)
    csv_path = tmp_path / "s.csv"
    write_samples(csv_path, samples)
    code, out, err = run_cli(["calibrate", "solve", str(csv_path), "--config", str(DESK)], capsys)
    assert code == 0, err
    assert "frame: the new anchors are the best-fit rigid (Kabsch) alignment" in out
    assert "the layout's spread along x (anchors 1, 2 against 3, 4)" in out
    assert "held near the configured values" in out
    assert "verdict: PASS" in out
    for i in range(1, 5):
        assert f"\n{i:>6} {i - 1:>4}  " in out  # one row per anchor: number, node


def test_failed_gates_refuse_to_write(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg_path = hangprinter_desk_config(tmp_path)
    rig = make_rig(DESK, seed=3, raise_diagonal_m=0.2)
    samples, _ = sample_set(rig)
    rev = samples.motor_rev.copy()
    rev[12:, 2] += 0.2  # cable 3 slipped 19 mm half-way through
    csv_path = tmp_path / "s.csv"
    write_samples(csv_path, cal.Samples(samples.node_ids, rev, samples.believed_m))
    new_path = tmp_path / "new.toml"
    args = ["calibrate", "solve", str(csv_path), "--config", str(cfg_path)]
    code, out, err = run_cli([*args, "--write", str(new_path)], capsys)
    assert code == 1
    assert "verdict: FAIL (rms" in out
    assert "not writing: the calibration failed its gates (rms" in err
    assert not new_path.exists()
    code, out, _ = run_cli(args, capsys)  # no --write: still a failure exit
    assert code == 1


@pytest.mark.parametrize(
    ("rows", "reason"),
    [
        (5, "5 poses give 20 equations for 25 unknowns"),
        ("flat", "lie within"),
    ],
)
def test_degenerate_samples_are_refused_with_reasons(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], rows: Any, reason: str
) -> None:
    rig = make_rig(DESK, seed=2, raise_diagonal_m=0.2)
    if rows == "flat":
        poses = rig.poses(25)
        poses[:, 2] = 0.3
        samples = cal.Samples(rig.node_ids, rig.turns(poses), poses)
    else:
        samples, _ = sample_set(rig, n=rows)
    csv_path = tmp_path / "s.csv"
    write_samples(csv_path, samples)
    cfg_path = hangprinter_desk_config(tmp_path)
    code, out, err = run_cli(
        ["calibrate", "solve", str(csv_path), "--config", str(cfg_path), "--json"], capsys
    )
    assert code == 1
    assert reason in err
    assert json.loads(out) == {"ok": False, "error": err.strip().removeprefix("cablebot: ")}


def test_bad_inputs_exit_1_with_the_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    csv_path = tmp_path / "s.csv"
    csv_path.write_text("node_0_rev,node_1_rev,x_m,y_m,z_m\n")
    code, _, err = run_cli(["calibrate", "solve", str(csv_path), "--config", str(DESK)], capsys)
    assert code == 1 and "missing column(s) node_2_rev, node_3_rev" in err
    code, _, err = run_cli(
        ["calibrate", "solve", str(tmp_path / "none.csv"), "--config", str(DESK)], capsys
    )
    assert code == 1 and "cannot read" in err
    code, _, err = run_cli(
        ["calibrate", "solve", str(csv_path), "--config", str(DESK), "--hold-std-m", "0"], capsys
    )
    assert code == 1 and "hold_std_m must be a finite number > 0" in err
    code, _, err = run_cli(["calibrate", "collect", str(csv_path), "--auto", "0"], capsys)
    assert code == 1 and "--auto needs a number of poses >= 1" in err
    code, _, err = run_cli(["calibrate", "collect", str(csv_path), "--auto", "3"], capsys)
    assert code == 1 and "exists (use --force to overwrite)" in err


# --------------------------------------------------------------------------------------------
# collect against a running daemon


def desk_daemon_config(tmp_path: Path) -> tuple[Path, str, str]:
    """config/desk.toml on simulated nodes: its own udp_multicast port (host-only), loopback
    Zenoh on a free port, faster motion limits so a test visits a pose in about a second."""
    data = tomllib.loads(DESK.read_text())
    name = f"cal{uuid.uuid4().hex[:8]}"
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    prefix = f"cablebot/{name}"
    data["name"] = name
    data["bus"] = {
        "interface": "udp_multicast",
        "channel": f"239.74.{random.randint(1, 254)}.{random.randint(1, 254)}",
        "options": {"port": random.randint(40000, 49000), "hop_limit": 0},
    }
    data["loop"] = {"rate_hz": 250.0, "realtime": False, "publish_every": 5}
    # The simulated drives' watchdog too: a stalled loop on a loaded host must not idle them.
    data["sim"] = {"enabled": True, "watchdog_timeout_s": 2.0}
    data["limits"].update(
        {
            "max_speed_mps": 1.0,
            "max_accel_mps2": 2.0,
            "default_speed_mps": 0.6,
            "max_cable_speed_mps": 1.5,
        }
    )
    # This tests sample collection, not fault detection: a loaded host may delay the nodes.
    data["faults"].update(
        {"stale_timeout_s": 0.5, "heartbeat_timeout_s": 2.0, "tracking_max_m": 0.1}
    )
    data["homing"] = {"power_up_position_m": [0.0, 0.0, 0.3]}
    data["zenoh"] = {
        "prefix": prefix,
        "mode": "peer",
        "listen": [endpoint],
        "multicast_scouting": False,
    }
    path = tmp_path / f"{name}.toml"
    path.write_text(to_toml(data))
    return path, endpoint, prefix


@pytest.fixture(scope="module")
def desk_daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, str, str]]:
    cfg, endpoint, prefix = desk_daemon_config(tmp_path_factory.mktemp("cal"))
    proc = Proc([*CABLEBOT, "run", "--config", str(cfg), "--status-every", "0"], "daemon")
    session = None
    try:
        session = zenoh_session(endpoint, 30.0)
        deadline = time.monotonic() + 30.0
        while zquery(session, f"{prefix}/status").get("state") != "HOLDING":
            assert time.monotonic() < deadline, proc.log()
            time.sleep(0.1)
        yield cfg, endpoint, prefix
    finally:
        if session is not None:
            session.close()
        assert proc.terminate(10.0) == 0, proc.log()


def _daemon_state(desk_daemon: tuple[Path, str, str]) -> str:
    """The daemon's state, its reason and loop figures (for a failure message)."""
    _, endpoint, prefix = desk_daemon
    session = zenoh_session(endpoint, 30.0)
    try:
        st = zquery(session, f"{prefix}/status")
    finally:
        session.close()
    return f"daemon: {st.get('state')} ({st.get('reason')}); loop {st.get('loop')}"


def collect(
    desk_daemon: tuple[Path, str, str], *args: str, stdin: str | None = None, timeout_s: float = 180
) -> subprocess.CompletedProcess[str]:
    _, endpoint, prefix = desk_daemon
    return subprocess.run(
        [*CABLEBOT, "calibrate", "collect", *args, "--connect", endpoint, "--prefix", prefix],
        cwd=REPO,
        input=stdin,
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )


def read_rows(path: Path) -> tuple[list[str], list[list[float]]]:
    lines = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("#")]
    rows = list(csv.reader(io.StringIO("\n".join(lines))))
    return rows[0], [[float(v) for v in r] for r in rows[1:]]


@pytest.mark.slow
def test_collect_auto_visits_spread_poses_and_solve_recovers_the_config(
    desk_daemon: tuple[Path, str, str], tmp_path: Path
) -> None:
    cfg, _, _ = desk_daemon
    out = tmp_path / "auto.csv"
    res = collect(desk_daemon, str(out), "--auto", "14")
    assert res.returncode == 0, res.stdout + res.stderr + _daemon_state(desk_daemon)
    assert "14 sample(s)" in res.stdout
    # an estimate up front, and at every pose how far along and how long is left
    assert re.search(r"visiting 14 poses: [0-9.]+ m at [0-9.]+ m/s, about \d+ (s|min);", res.stdout)
    assert re.search(r"pose 14/14 \(\d+ (s|min) in, about \d+ (s|min) left\): move to", res.stdout)
    header, rows = read_rows(out)
    assert header == ["node_0_rev", "node_1_rev", "node_2_rev", "node_3_rev", "x_m", "y_m", "z_m"]
    assert len(rows) == 14
    poses = np.array(rows)[:, 4:]
    # Spread over the workspace (|x|, |y| <= 0.45, 0.01 <= z <= 0.7), kept inside it.
    assert np.ptp(poses[:, 0]) > 0.6 and np.ptp(poses[:, 1]) > 0.6 and np.ptp(poses[:, 2]) > 0.4
    assert np.all(np.abs(poses[:, :2]) < 0.45) and np.all(
        (poses[:, 2] > 0.01) & (poses[:, 2] < 0.7)
    )
    # The samples are the daemon's own belief: the solve finds the configured anchors again.
    solved = subprocess.run(
        [*CABLEBOT, "calibrate", "solve", str(out), "--config", str(cfg), "--json"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert solved.returncode == 0, solved.stdout + solved.stderr
    data = json.loads(solved.stdout)
    assert data["ok"] is True
    assert np.abs(np.array(data["anchors_m"]) - np.array(data["config_anchors_m"])).max() < 1e-4
    assert data["rms_residual_m"] < 1e-5


@pytest.mark.slow
def test_collect_manual_records_the_pose_at_each_enter(
    desk_daemon: tuple[Path, str, str], tmp_path: Path
) -> None:
    _, endpoint, prefix = desk_daemon
    out = tmp_path / "manual.csv"
    res = collect(desk_daemon, str(out), stdin="\n\nq\n", timeout_s=60)
    assert res.returncode == 0, res.stdout + res.stderr + _daemon_state(desk_daemon)
    _, rows = read_rows(out)
    assert len(rows) == 2
    # the robot did not move between the two: the second sample is the first pose again
    assert "warning: sample 2 is sample 1's pose again" in res.stderr, res.stderr
    assert "move the robot to a new pose before the next sample" in res.stderr
    assert "sample 1 is" not in res.stderr
    session = zenoh_session(endpoint)
    try:
        st = zquery(session, f"{prefix}/status")
    finally:
        session.close()
    by_node = {ax["node_id"]: ax["position_rev"] for ax in st["axes"]}
    for row in rows:  # the robot holds still: every row is the status' turns and pose
        assert row[:4] == pytest.approx([by_node[i] for i in range(4)], abs=1e-4)
        assert row[4:] == pytest.approx(st["pose"]["position_m"], abs=1e-4)
    # --auto moves the robot: refused unless it is armed and holding; no file is made.
    session = zenoh_session(endpoint)
    try:
        assert "error" not in zquery(session, f"{prefix}/cmd/disarm")
        refused = collect(desk_daemon, str(tmp_path / "d.csv"), "--auto", "3", timeout_s=60)
        assert refused.returncode == 1, refused.stdout + refused.stderr
        assert "it must be armed and holding a valid pose (state DISARMED" in refused.stderr
        assert not (tmp_path / "d.csv").exists()
    finally:
        zquery(session, f"{prefix}/cmd/arm")
        session.close()
    # No daemon answering: the no-daemon exit code, no file.
    gone = subprocess.run(
        [
            *CABLEBOT,
            *("calibrate", "collect", str(tmp_path / "x.csv"), "--auto", "3"),
            *("--connect", f"tcp/127.0.0.1:{free_tcp_port()}", "--prefix", prefix),
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert gone.returncode == exitcodes.NO_DAEMON, gone.stderr
    assert not (tmp_path / "x.csv").exists()


def test_a_sample_at_an_earlier_pose_is_named() -> None:
    from controller.cli.calibrate import same_pose_as
    from controller.core.calibration import DISTINCT_POSE_M

    earlier = [[0.0, 0.0, 0.3], [0.1, 0.0, 0.3], [0.1, 0.0004, 0.3]]
    found = same_pose_as([0.1, 0.0003, 0.3], earlier)
    assert found is not None and found[0] == 3 and found[1] == pytest.approx(1e-4)
    assert same_pose_as([0.0, 0.0, 0.3 + 0.9 * DISTINCT_POSE_M], earlier) == (
        1,
        pytest.approx(0.9 * DISTINCT_POSE_M),
    )
    assert same_pose_as([0.0, 0.0, 0.3 + DISTINCT_POSE_M], earlier) is None
    assert same_pose_as([0.0, 0.0, 0.3], []) is None


@pytest.mark.parametrize("config", [None, DESK])
def test_auto_poses_satisfy_the_solver_that_recommends_them(config: Path | None) -> None:
    """`collect --auto` (its default count, the built-in robot's or the desk's workspace) gives
    poses the solver has nothing to warn about: the recommendation, the thresholds and the
    pose generator agree."""
    from controller.cli.calibrate import auto_poses
    from controller.core.kinematics import Geometry
    from controller.core.workspace import Workspace
    from tests.core.test_calibration import believed_poses, make_rig

    cfg = load_config(config)
    n = cal.recommended_poses(len(cfg.reels))
    assert n == 28
    poses = np.array(auto_poses(cfg.summary(), n, None, cfg.homing.power_up_position_m))
    rig = make_rig(config if config is not None else REPO / "config" / "paper-acre.toml", seed=3)
    assert np.allclose(rig.config_anchors_m, cfg.anchors_m)
    turns = rig.turns(poses)
    believed, _ = believed_poses(rig, poses, turns)
    samples = cal.Samples(rig.node_ids, turns, believed)
    _, _, (z_lo, z_hi) = Workspace.from_limits(cfg.limits, Geometry(cfg.anchors_m)).box()
    res = cal.calibrate(rig.config_anchors_m, rig.reels, samples, pose_height_m=z_hi - z_lo)
    assert not [w for w in res.warnings if "few poses" in w or "coplanar" in w], res.warnings
    if config is None:  # wide and low: without the workspace's height the poses look flat
        res = cal.calibrate(rig.config_anchors_m, rig.reels, samples)
        assert any("poses nearly coplanar" in w for w in res.warnings)
    short = cal.calibrate(
        rig.config_anchors_m,
        rig.reels,
        cal.Samples(rig.node_ids, turns[:25], believed[:25]),
        pose_height_m=z_hi - z_lo,
    )
    assert "few poses (25): 28 or more give a better check" in short.warnings


def test_solve_defaults_to_the_built_in_robot(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = make_rig(REPO / "config" / "paper-acre.toml", seed=1)
    samples, _ = sample_set(rig, n=28)
    path = tmp_path / "s.csv"
    write_samples(path, samples)
    code, out, err = run_cli(["calibrate", "solve", str(path), "--json"], capsys)
    assert "--config" not in err, err
    data = json.loads(out)
    assert np.allclose(data["config_anchors_m"], load_config(None).anchors_m)
    code, out, _ = run_cli(["calibrate", "solve", str(path)], capsys)
    assert out.startswith(f"calibration of the built-in robot from {path}: 28 poses")
    code, _, err = run_cli(
        ["calibrate", "solve", str(path), "--write", str(tmp_path / "n.toml")], capsys
    )
    assert code == 1 and "--write edits the robot file given with --config" in err


class _NoSub:
    def undeclare(self) -> None:
        pass


class _FakeSession:
    def declare_subscriber(self, key: str, handler: Any) -> _NoSub:
        return _NoSub()


def test_ctrl_c_during_collect_auto_brakes_to_a_hold(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C while `collect --auto` drives the robot sends `stop`, says so and exits 130
    (a fake session: the first move is taken, then Ctrl-C comes while waiting for the pose)."""
    from controller.cli import calibrate, client

    sent: list[str] = []
    status = {
        "state": "HOLDING",
        "pose": {"position_m": [0.0, 0.0, 0.4]},
        "config": {"name": "desk", "reels": [{"node_id": n} for n in range(4)]},
    }

    def fake_query(session: Any, key: str, payload: Any, timeout_s: float) -> Any:
        sent.append(key.rsplit("/", 2)[-1] if "cmd/" not in key else key.split("cmd/")[1])
        if key.endswith("/status"):
            return status
        if key.endswith("cmd/stop"):
            return {"ok": True, "state": "STOPPING"}
        return {"ok": True}

    def ctrl_c(*_a: Any, **_k: Any) -> Any:
        raise KeyboardInterrupt

    monkeypatch.setattr(calibrate, "query", fake_query)
    monkeypatch.setattr(client, "query", fake_query)
    monkeypatch.setattr(calibrate, "auto_poses", lambda *a: [(0.1, 0.0, 0.4), (0.2, 0.0, 0.4)])
    monkeypatch.setattr(calibrate, "auto_speed_mps", lambda *a: (0.2, 0.5))
    monkeypatch.setattr(calibrate, "wait_still", ctrl_c)
    monkeypatch.setattr(calibrate, "_run", lambda args, body: body(_FakeSession()))
    code, out, err = run_cli(
        ["calibrate", "collect", str(tmp_path / "s.csv"), "--auto", "2"], capsys
    )
    assert code == exitcodes.INTERRUPTED, (out, err)
    assert "interrupted: braking to a hold" in err
    assert sent[-1] == "stop", sent
    assert "move" in sent


def test_collect_auto_without_a_count_visits_the_recommended_poses(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A bare `collect --auto` (as the docs show it) visits as many poses as `calibrate solve`
    recommends for the daemon's cables (28 for four), not none (a fake session: the first
    wait for a still pose ends the run)."""
    from controller.cli import calibrate, client
    from controller.core.calibration import recommended_poses

    asked: list[int] = []
    status = {
        "state": "HOLDING",
        "pose": {"position_m": [0.0, 0.0, 0.4]},
        "config": {"name": "desk", "reels": [{"node_id": n} for n in range(4)]},
    }

    def fake_query(session: Any, key: str, payload: Any, timeout_s: float) -> Any:
        return status if key.endswith("/status") else {"ok": True, "state": "HOLDING"}

    def poses(summary: Any, n: int, *_a: Any) -> list[tuple[float, float, float]]:
        asked.append(n)
        return [(0.1, 0.0, 0.4)] * n

    def ctrl_c(*_a: Any, **_k: Any) -> Any:
        raise KeyboardInterrupt

    monkeypatch.setattr(calibrate, "query", fake_query)
    monkeypatch.setattr(client, "query", fake_query)
    monkeypatch.setattr(calibrate, "auto_poses", poses)
    monkeypatch.setattr(calibrate, "auto_speed_mps", lambda *a: (0.2, 0.5))
    monkeypatch.setattr(calibrate, "wait_still", ctrl_c)
    monkeypatch.setattr(calibrate, "_run", lambda args, body: body(_FakeSession()))
    code, out, err = run_cli(["calibrate", "collect", str(tmp_path / "s.csv"), "--auto"], capsys)
    assert code == exitcodes.INTERRUPTED, (out, err)
    assert "needs a number of poses" not in err, err
    assert asked == [recommended_poses(4)] == [28], (asked, out, err)
    assert f"visiting {recommended_poses(4)} poses" in out


def test_solve_takes_the_stretch_of_elastic_lines_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Samples of config/hangprinter-v4.toml's elastic lines (EA 20 kN) at its own anchors, as
    its simulator records them (each reel paid out the length shortened by the stretch under
    the planned tensions): `calibrate solve` says it takes the stretch out and leaves every
    anchor where it is; fitted as rigid lines the anchors would move by centimetres."""
    from controller.core.stretch import CableStretch
    from controller.service.config import tension_check

    path = REPO / "config" / "hangprinter-v4.toml"
    cfg = load_config(path)
    assert cfg.payload is not None and cfg.tension is not None
    model = CableStretch(
        cfg.geometry,
        [r.cable_ea_n for r in cfg.reels],
        tension_check(cfg.payload, cfg.tension, cfg.geometry),
    )
    from controller.core.workspace import Workspace

    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    poses = cal.spread_poses(
        28,
        (-0.6, -0.6, 0.05),
        (0.6, 0.6, 1.2),
        lambda p: ws.check_target(p) is None and model.check.solve(p).margin_n > 3,
    )
    rows = [cal.samples_header(cfg.node_ids)]
    for p in poses:
        paid, _ = model.ipk(p)
        turns = [r.reel.position_rev(x) + 3.0 for r, x in zip(cfg.reels, paid, strict=True)]
        rows.append(cal.format_sample_row(turns, list(p)))
    csv_path = tmp_path / "hp4.csv"
    csv_path.write_text("\n".join(",".join(map(str, r)) for r in rows) + "\n")
    code, out, err = run_cli(["calibrate", "solve", str(csv_path), "--config", str(path)], capsys)
    assert code == 0, (out, err)
    assert "stretch: each cable's length is what its reel paid out, stretched by" in out
    code, out, _ = run_cli(
        ["calibrate", "solve", str(csv_path), "--config", str(path), "--json"], capsys
    )
    res = json.loads(out)
    assert 2e-3 < res["stretch_m"] < 10e-3
    change = np.linalg.norm(np.array(res["anchor_change_m"]), axis=1)
    assert change.max() < 1e-5, change
    assert res["ok"] and res["rms_residual_m"] < 1e-6
    rigid = cal.calibrate(
        cfg.anchors_m,
        [r.reel for r in cfg.reels],
        cal.parse_samples(csv_path.read_text(), "hp4.csv", cfg.node_ids),
        hanging=False,
    )
    assert np.linalg.norm(rigid.anchors_m - np.asarray(cfg.anchors_m), axis=1).max() > 5e-3
