"""`cablebot record`, `replay` and `plot` against a real daemon process.

- a 3 s recording of a moving robot, read back with the `mcap` reader, has the poses at the
  daemon's rate (within 10 %), every state change a separate subscriber saw, the status
  samples, the streamed set-point, and the daemon's configuration;
- a recorder killed with SIGKILL leaves a file that the `mcap` reader reads up to its last
  flush;
- `replay` gives a subscriber the recorded pose and state payloads (same seq, same positions)
  with the recorded timing, answers status queries, never republishes a command key, and
  refuses to run where a live daemon uses the prefix;
- `plot` writes the four figures from the recording (and from the killed one).
"""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller.cli import exitcodes
from controller.cli.record import META_CONFIG, META_RECORDING, McapRecorder, Recording
from controller.service.config import load_config
from tests.daemon_procs import CABLEBOT, REPO, Proc, free_tcp_port, zenoh_session, zquery
from tests.live_daemon import RATE_HZ, Daemon, live_daemon, wait_holding_at_rest

mcap = pytest.importorskip("mcap")

pytestmark = pytest.mark.slow

RECORD_S = 3.0


@dataclass
class Run:
    """A recording made while the robot moved, and what the test saw meanwhile."""

    path: Path
    config: Path
    prefix: str
    states_seen: list[dict[str, Any]]
    setpoint: list[float]


def _mcap_messages(path: Path) -> list[tuple[str, Any]]:
    """(topic, mcap Message) of a finished file, with the mcap package's own reader."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        reader = make_reader(f)
        return [(ch.topic, msg) for _, ch, msg in reader.iter_messages(log_time_order=False)]


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Daemon, Path]]:
    with live_daemon(tmp_path_factory.mktemp("rec")) as d:
        yield d


@pytest.fixture(scope="module")
def run(robot: tuple[Daemon, Path], tmp_path_factory: pytest.TempPathFactory) -> Run:
    d, cfg = robot
    start = wait_holding_at_rest(d)["pose"]["position_m"]
    path = tmp_path_factory.mktemp("rec-run") / "moving.mcap"
    rec = Proc(
        [
            *CABLEBOT,
            "record",
            str(path),
            "--duration",
            str(RECORD_S),
            "--status-hz",
            "10",
            "--config",
            str(cfg),
            "--connect",
            d.endpoint,
            "--prefix",
            d.prefix,
        ],
        "record",
    )
    rec.wait_line("recording", 30.0)
    while not d.states.empty():
        d.states.get_nowait()
    target = [start[0] + 0.3, start[1] - 0.1, start[2] + 0.1]
    assert (
        d.query("cmd/move", json.dumps({"position_m": target, "speed_mps": 1.0}).encode())[0]
        == "ok"
    )
    _wait_state(d, "HOLDING", 10.0)
    assert d.query("cmd/disarm")[0] == "ok"
    assert d.query("cmd/arm")[0] == "ok"
    _wait_state(d, "HOLDING", 10.0)
    setpoint = [target[0] - 0.02, target[1], target[2]]
    d.session.put(f"{d.prefix}/setpoint", json.dumps({"position_m": setpoint}))
    deadline = time.monotonic() + 30.0
    while rec.p.poll() is None:
        assert time.monotonic() < deadline, rec.log()
        time.sleep(0.05)
    assert rec.p.returncode == 0, rec.log()
    assert "wrote" in rec.wait_line("wrote", 5.0)
    seen = []
    while not d.states.empty():
        seen.append(d.states.get_nowait())
    return Run(path, cfg, d.prefix, seen, setpoint)


def _wait_state(d: Daemon, state: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while d.status()["state"] != state:
        assert time.monotonic() < deadline, d.proc.log()
        time.sleep(0.02)


# ------------------------------------------------------------------------------ record


def test_recording_has_poses_at_the_daemon_rate_and_every_state_change(run: Run) -> None:
    msgs = _mcap_messages(run.path)
    topics = {t for t, _ in msgs}
    p = run.prefix
    assert {f"{p}/pose", f"{p}/state", f"{p}/status", f"{p}/alive", f"{p}/setpoint"} <= topics

    poses = [m for t, m in msgs if t == f"{p}/pose"]
    decoded = [json.loads(m.data) for m in poses]
    span_s = (poses[-1].log_time - poses[0].log_time) * 1e-9
    rate = (len(poses) - 1) / span_s
    seqs = [x["seq"] for x in decoded]
    seq_rate = (seqs[-1] - seqs[0]) / ((decoded[-1]["stamp_ns"] - decoded[0]["stamp_ns"]) * 1e-9)
    missing = (seqs[-1] - seqs[0] + 1) - len(seqs)
    print(f"recorded {len(poses)} poses over {span_s:.2f} s: {rate:.1f} Hz, {missing} missing")
    assert span_s > RECORD_S - 0.5
    # What the daemon did meanwhile, by its own recorded status: its loop keeps the grid of
    # RATE_HZ (ticks run plus deadlines it skipped after an overrun on a busy machine), and
    # it publishes a pose every tick it runs; the recorder keeps the pace of what it publishes.
    loops = [(m.log_time, json.loads(m.data)["loop"]) for t, m in msgs if t == f"{p}/status"]
    (t_a, a), (t_b, b) = loops[0], loops[-1]
    loop_s = (t_b - t_a) * 1e-9
    assert loop_s > RECORD_S - 1.0, loops
    tick_hz = (b["ticks"] - a["ticks"]) / loop_s
    grid_hz = (b["ticks"] + b["skipped"] - a["ticks"] - a["skipped"]) / loop_s
    print(f"daemon: {tick_hz:.1f} Hz ticks, {grid_hz:.1f} Hz grid; published {seq_rate:.1f} Hz")
    assert abs(grid_hz - RATE_HZ) <= 0.1 * RATE_HZ
    assert abs(seq_rate - tick_hz) <= 0.1 * tick_hz
    assert abs(rate - seq_rate) <= 0.1 * seq_rate
    assert missing <= 0.1 * len(seqs)
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    # the recorded fields: sequence = seq, publish_time = stamp_ns, payload = the sample
    for m, x in zip(poses, decoded, strict=True):
        assert m.sequence == x["seq"] and m.publish_time == x["stamp_ns"]
    assert any(x["state"] == "MOVING" for x in decoded)

    # every state change a separate subscriber saw while the recorder ran (those published
    # in its last 0.3 s may have reached one and not the other)
    end_ns = max(m.log_time for _, m in msgs) - 300_000_000
    states = [json.loads(m.data) for t, m in msgs if t == f"{p}/state"]
    seen = [s for s in run.states_seen if s["stamp_ns"] <= end_ns]
    assert [s for s in states if s["stamp_ns"] <= end_ns] == seen, (states, run.states_seen)
    names = [s["state"] for s in states]
    assert names[:5] == ["MOVING", "HOLDING", "DISARMED", "ARMING", "HOLDING"], names

    status = [json.loads(m.data) for t, m in msgs if t == f"{p}/status"]
    assert abs(len(status) - 10 * RECORD_S) <= 5, len(status)
    assert all(s["state"] in {"HOLDING", "MOVING", "DISARMED", "ARMING"} for s in status)
    sp = [json.loads(m.data) for t, m in msgs if t == f"{p}/setpoint"]
    assert sp == [{"position_m": run.setpoint}]
    alive = [json.loads(m.data) for t, m in msgs if t == f"{p}/alive"]
    assert alive == [{"alive": True}]


def test_recording_stores_the_configuration(run: Run) -> None:
    from mcap.reader import make_reader

    with open(run.path, "rb") as f:
        reader = make_reader(f)
        meta = [(m.name, m.metadata) for m in reader.iter_metadata()]
        attachments = list(reader.iter_attachments())
        summary = reader.get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.chunk_count >= 3  # flushed about every second
    sources = [m["source"] for name, m in meta if name == META_CONFIG]
    assert sources == ["file", "status"]
    rec_meta = next(m for name, m in meta if name == META_RECORDING)
    assert rec_meta["prefix"] == run.prefix
    assert [(a.name, a.data) for a in attachments] == [(run.config.name, run.config.read_bytes())]
    rec = Recording(run.path)
    assert sum(1 for _ in rec.messages()) > 0 and rec.complete and rec.error is None
    cfg = rec.config_summary()
    assert cfg is not None
    assert [tuple(r["anchor_m"]) for r in cfg["reels"]] == list(load_config(run.config).anchors_m)
    assert rec.recorded_prefix() == run.prefix


def test_killed_recorder_leaves_a_readable_file(robot: tuple[Daemon, Path], tmp_path: Path) -> None:
    from mcap.reader import NonSeekingReader

    d, _ = robot
    path = tmp_path / "killed.mcap"
    rec = Proc(
        [
            *CABLEBOT,
            "record",
            str(path),
            "--flush-s",
            "0.5",
            "--connect",
            d.endpoint,
            "--prefix",
            d.prefix,
        ],
        "record",
    )
    rec.wait_line("recording", 30.0)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 2.5:  # let it record a few flushes
        assert rec.p.poll() is None, rec.log()
        time.sleep(0.05)
    os.kill(rec.p.pid, signal.SIGKILL)
    killed_after_s = time.monotonic() - t0
    rec.p.wait(10.0)
    assert rec.p.returncode == -signal.SIGKILL

    poses = []
    with open(path, "rb") as f:
        try:
            for _, ch, msg in NonSeekingReader(f).iter_messages(log_time_order=False):
                if ch.topic == f"{d.prefix}/pose":
                    poses.append(json.loads(msg.data))
        except mcap.exceptions.EndOfFile:
            pass  # no footer: the recorder never finished, as expected
    # everything up to the last flush (at most 0.5 s plus a scheduling delay before the kill)
    expected = RATE_HZ * (killed_after_s - 0.5 - 0.5)
    print(f"killed after {killed_after_s:.2f} s: {len(poses)} poses readable")
    assert len(poses) >= expected, (len(poses), expected)
    seqs = [p["seq"] for p in poses]
    assert seqs == sorted(seqs)
    r = Recording(path)
    assert [json.loads(m.data)["seq"] for m in r.messages() if m.topic.endswith("/pose")] == seqs
    assert not r.complete
    assert r.recorded_prefix() == d.prefix

    out = tmp_path / "img"
    cp = subprocess.run(
        [*CABLEBOT, "plot", str(path), "--out", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert cp.returncode == 0, cp.stdout + cp.stderr
    assert "ends early" in cp.stdout
    from controller.cli.plot import FIGURES

    assert len(list(out.glob("killed-*.png"))) == len(FIGURES) + 1  # and the speed figure


def test_recorder_skips_payloads_that_are_not_json(tmp_path: Path) -> None:
    with open(tmp_path / "x.mcap", "wb") as f:
        rec = McapRecorder(f, "cablebot/x")
        assert rec.add("cablebot/x/pose", b'{"seq": 7, "stamp_ns": 5}', 10)
        assert not rec.add("cablebot/x/pose", b"\xff not json", 11)
        rec.close()
    r = Recording(tmp_path / "x.mcap")
    got = list(r.messages())
    assert [(m.sequence, m.publish_time_ns, m.log_time_ns) for m in got] == [(7, 5, 10)]
    assert rec.not_json == 1 and r.complete


def test_record_without_daemon_exits_no_daemon(tmp_path: Path) -> None:
    cp = subprocess.run(
        [
            *CABLEBOT,
            "record",
            str(tmp_path / "x.mcap"),
            "--connect",
            f"tcp/127.0.0.1:{free_tcp_port()}",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert cp.returncode == exitcodes.NO_DAEMON, cp.stdout + cp.stderr
    assert not (tmp_path / "x.mcap").exists()


def _record_cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*CABLEBOT, "record", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_record_on_a_prefix_no_daemon_lives_on_exits_no_daemon(
    robot: tuple[Daemon, Path], tmp_path: Path
) -> None:
    d, _cfg = robot
    out = tmp_path / "nope.mcap"
    cp = _record_cli(str(out), "--connect", d.endpoint, "--prefix", "cablebot/nope")
    assert cp.returncode == exitcodes.NO_DAEMON, cp.stdout + cp.stderr
    assert d.prefix in cp.stderr  # names the live prefix
    assert not out.exists()


def test_record_refuses_to_overwrite_without_force(tmp_path: Path) -> None:
    out = tmp_path / "kept.mcap"
    out.write_bytes(b"keep me")
    cp = _record_cli(str(out), "--connect", f"tcp/127.0.0.1:{free_tcp_port()}")
    assert cp.returncode == exitcodes.REFUSED, cp.stdout + cp.stderr
    assert "--force" in cp.stderr
    assert out.read_bytes() == b"keep me"


SLOW_ROBOT = r"""
import sys, threading, time, types, zenoh
from controller.service.zenoh_io import session_config

endpoint, prefix, delay_s = sys.argv[1], sys.argv[2], float(sys.argv[3])
session = zenoh.open(session_config(types.SimpleNamespace(listen=[endpoint])))
held = []
lock = threading.Lock()

def on_query(query):
    with lock:
        held.append((time.monotonic() + delay_s, query))

def answer():
    while True:
        now = time.monotonic()
        with lock:
            due = [q for t, q in held if t <= now]
            held[:] = [(t, q) for t, q in held if t > now]
        for q in due:
            try:
                q.reply(f"{prefix}/status", b'{"state": "HOLDING"}')
                q.drop()
            except Exception:
                pass
        time.sleep(0.01)

queryable = session.declare_queryable(f"{prefix}/status", on_query)
token = session.liveliness().declare_token(f"{prefix}/alive")
threading.Thread(target=answer, daemon=True).start()
print("READY", flush=True)
time.sleep(3600)
"""
"""A robot that answers every status query `delay_s` late, as a daemon on a loaded host does."""


@pytest.mark.timeout(300)
def test_record_exits_cleanly_with_status_replies_still_on_their_way(tmp_path: Path) -> None:
    """The status queries' reply callbacks are still waiting when the recorder stops (the
    robot answers 1 s late). They must not run on daemon threads: one still inside Zenoh's
    native code at exit aborted the recorder after it wrote its file ("FATAL: exception not
    rethrown", exit 134)."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    robot = Proc([sys.executable, "-c", SLOW_ROBOT, endpoint, "cablebot/slow", "1.0"], "slow")
    try:
        robot.wait_line("READY", 60.0)
        for i in range(3):
            out = tmp_path / f"slow{i}.mcap"
            cp = _record_cli(
                str(out),
                "--connect",
                endpoint,
                "--prefix",
                "cablebot/slow",
                "--duration",
                "1.5",
                "--status-hz",
                "1000",
            )
            assert "FATAL" not in cp.stderr, cp.stderr
            assert cp.returncode == exitcodes.OK, (i, cp.returncode, cp.stdout + cp.stderr)
            assert f"wrote {out}:" in cp.stdout, cp.stdout
            rec = Recording(out)
            assert sum(1 for _ in rec.messages()) > 0 and rec.complete, rec.error
    finally:
        robot.terminate()


# ------------------------------------------------------------------------------ replay


def _replay(run: Run, *extra: str) -> tuple[Proc, str]:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    proc = Proc(
        [
            *CABLEBOT,
            "replay",
            str(run.path),
            "--listen",
            endpoint,
            "--wait-subscriber",
            "30",
            *extra,
        ],
        "replay",
    )
    return proc, endpoint


def _follow_replay(run: Run, *extra: str) -> tuple[list[tuple[float, str, bytes]], dict[str, Any]]:
    """Run a replay, subscribe to everything under the prefix; return what arrived, with the
    arrival time, and a status reply obtained while it ran."""
    proc, endpoint = _replay(run, *extra)
    got: queue.Queue[tuple[float, str, bytes]] = queue.Queue()
    session = zenoh_session(endpoint, 30.0)
    status: dict[str, Any] = {}
    try:
        session.declare_subscriber(
            f"{run.prefix}/**",
            lambda s: got.put((time.monotonic(), str(s.key_expr), s.payload.to_bytes())),
        )
        first = got.get(timeout=30.0)
        deadline = time.monotonic() + 10.0
        while "config" not in status:  # replay answers once it reached a recorded status
            assert time.monotonic() < deadline, (status, proc.log())
            status = zquery(session, f"{run.prefix}/status", None, 5.0)
        deadline = time.monotonic() + 60.0
        while proc.p.poll() is None:
            assert time.monotonic() < deadline, proc.log()
            time.sleep(0.05)
        assert proc.p.returncode == 0, proc.log()
        time.sleep(0.2)
    finally:
        session.close()
        proc.terminate()
    items = [first]
    while not got.empty():
        items.append(got.get_nowait())
    return items, status


def test_replay_gives_the_recorded_samples_with_their_timing(run: Run) -> None:
    recorded = _mcap_messages(run.path)
    rec_pose = [m for t, m in recorded if t == f"{run.prefix}/pose"]
    rec_state = [m.data for t, m in recorded if t == f"{run.prefix}/state"]
    items, status = _follow_replay(run)
    poses = [data for _, key, data in items if key == f"{run.prefix}/pose"]
    # same payloads: same seq numbers, same positions, same stamps, in the same order
    assert poses == [m.data for m in rec_pose]
    assert [json.loads(p)["seq"] for p in poses] == [json.loads(m.data)["seq"] for m in rec_pose]
    assert [data for _, key, data in items if key == f"{run.prefix}/state"] == rec_state
    keys = {key for _, key, _ in items}
    assert keys == {f"{run.prefix}/pose", f"{run.prefix}/state"}, keys  # no set-point, ever
    # the timing: the replay lasts as long as the recording
    times = [t for t, key, _ in items if key == f"{run.prefix}/pose"]
    rec_span = (rec_pose[-1].log_time - rec_pose[0].log_time) * 1e-9
    span = times[-1] - times[0]
    print(f"recorded span {rec_span:.3f} s, replayed span {span:.3f} s")
    assert abs(span - rec_span) <= 0.1 * rec_span
    # status queries answered from the recording
    assert status.get("config", {}).get("name") == load_config(run.config).name, status


def test_replay_rate(run: Run) -> None:
    rec_pose = [m for t, m in _mcap_messages(run.path) if t == f"{run.prefix}/pose"]
    rec_span = (rec_pose[-1].log_time - rec_pose[0].log_time) * 1e-9
    items, _ = _follow_replay(run, "--rate", "3")
    times = [t for t, key, _ in items if key == f"{run.prefix}/pose"]
    assert len(times) == len(rec_pose)
    span = times[-1] - times[0]
    print(f"recorded span {rec_span:.3f} s, replayed at 3x in {span:.3f} s")
    # Each pose comes at its recorded time over 3, give or take 15 % of the replay's span,
    # after a common delivery delay. Judged on 80 % of them: a stall of the replayer or of
    # this subscriber on a busy machine makes the poses around it late, then the replayer
    # catches up on its schedule (a replay at the wrong rate puts most of them off).
    t0 = rec_pose[0].log_time
    offsets = sorted(t - (m.log_time - t0) * 1e-9 / 3 for t, m in zip(times, rec_pose, strict=True))
    mid = offsets[len(offsets) // 2]
    on_time = sum(abs(d - mid) <= 0.15 * rec_span / 3 for d in offsets)
    assert on_time >= 0.8 * len(offsets), (on_time, len(offsets), span, rec_span)


def test_replay_stopped_by_sigterm_says_so_of_a_complete_file(run: Run) -> None:
    """Stopped mid-way, replay says it stopped; it never blames the complete file."""
    recording = Recording(run.path)
    n_recorded = sum(1 for _ in recording.messages())
    assert recording.complete and n_recorded > 10
    proc, endpoint = _replay(run, "--rate", "0.05")  # 20x slower: still replaying when killed
    got: queue.Queue[bytes] = queue.Queue()
    session = zenoh_session(endpoint, 30.0)
    try:
        session.declare_subscriber(f"{run.prefix}/pose", lambda s: got.put(s.payload.to_bytes()))
        got.get(timeout=30.0)  # under way
    finally:
        session.close()
    proc.p.send_signal(signal.SIGTERM)
    try:
        assert proc.p.wait(timeout=30.0) == exitcodes.OK, proc.log()
    finally:
        proc.terminate()
    line = proc.wait_line("replay stopped after", 5.0)
    n = int(line.split("after ")[1].split()[0])
    assert 1 <= n < n_recorded, line
    assert "ends early" not in proc.log()


def test_replay_refuses_a_prefix_with_a_live_daemon(run: Run, robot: tuple[Daemon, Path]) -> None:
    d, _ = robot
    assert d.prefix == run.prefix
    cp = subprocess.run(
        [*CABLEBOT, "replay", str(run.path), "--connect", d.endpoint],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert cp.returncode == 1, cp.stdout + cp.stderr
    assert "a live cablebot daemon runs under" in cp.stderr


# ------------------------------------------------------------------------------ plot


def test_plot_makes_the_four_figures(run: Run, tmp_path: Path) -> None:
    from controller.cli.plot import FIGURES, SPEED_FIGURE, trace_from_recording

    tr = trace_from_recording(run.path)
    n_pose = sum(1 for t, _ in _mcap_messages(run.path) if t == f"{run.prefix}/pose")
    assert len(tr.t_s) == n_pose and tr.lengths_m.shape == (n_pose, 4)
    assert tr.shape is not None and tr.shape.anchors_m == load_config(run.config).anchors_m
    assert len(tr.status_t_s) == tr.setpoint_m.shape[0] >= 10
    assert float(np.nanmax(tr.tracking_error_m)) > 1e-4  # the move shows up
    assert tr.notes == []

    out = tmp_path / "img"
    cp = subprocess.run(
        [*CABLEBOT, "plot", str(run.path), "--out", str(out)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert cp.returncode == 0, cp.stdout + cp.stderr
    import matplotlib.image

    for fig in (*FIGURES, SPEED_FIGURE):
        png = out / f"moving-{fig}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        h, w = matplotlib.image.imread(png).shape[:2]
        assert w >= 1000 and h >= 500, (png, w, h)


def test_plot_refuses_a_file_without_poses(tmp_path: Path) -> None:
    with open(tmp_path / "empty.mcap", "wb") as f:
        McapRecorder(f, "cablebot/x").close()
    cp = subprocess.run(
        [*CABLEBOT, "plot", str(tmp_path / "empty.mcap"), "--out", str(tmp_path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert cp.returncode == 1 and "no pose samples" in cp.stderr, cp.stderr
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file at all")
    cp = subprocess.run(
        [*CABLEBOT, "plot", str(tmp_path / "junk.mcap"), "--out", str(tmp_path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert cp.returncode == 1 and "cannot read" in cp.stderr, cp.stderr
