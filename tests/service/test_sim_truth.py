"""The simulator's ground truth on `<prefix>/sim/truth`: the physical plant's true effector
position and tensions, published by a real daemon that simulates its drives in-process; with
the cables' stretch in the controller's config the published pose sits on the truth."""

from __future__ import annotations

import json
import math
import queue
import time
import uuid
from pathlib import Path
from typing import Any

import pytest

from controller.core.plant import PlantParams, ReelPlant
from controller.core.reel import ReelModel
from controller.service.config import paper_robot_data
from controller.service.simulated import TRUTH_KEY, TruthFeed, truth_payload
from tests.daemon_procs import CABLEBOT, Proc, free_tcp_port, to_toml, zenoh_session

ANCHORS = [(-1.0, -1.0, 2.0), (-1.0, 1.0, 2.0), (1.0, 1.0, 2.0), (1.0, -1.0, 2.0)]


def small_plant() -> ReelPlant:
    reel = ReelModel(metres_per_rev=0.1)
    params = PlantParams(ANCHORS, 1e5, 1.0)
    turns = [math.dist(a, (0.0, 0.0, 1.0)) / 0.1 for a in ANCHORS]
    return ReelPlant(params, [reel] * 4, (0.0, 0.0, 1.0), turns)


def test_truth_payload_is_the_plants_position_and_tensions() -> None:
    plant = small_plant()
    data = json.loads(truth_payload(plant) or b"")
    assert data["position_m"] == list(plant.position_m)
    assert data["tensions_n"] == list(plant.tensions_n)
    assert math.dist(data["position_m"], (0.0, 0.0, 1.0)) < 1e-9

    class Broken:
        position_m = (0.0, math.nan, 1.0)
        tensions_n = (1.0, 1.0, 1.0, 1.0)

    assert truth_payload(Broken()) is None  # never a NaN on the wire


def test_truth_feed_puts_at_its_period_and_survives_put_errors() -> None:
    got: queue.Queue[bytes] = queue.Queue()
    calls = [0]

    def put(data: bytes) -> None:
        calls[0] += 1
        if calls[0] == 2:
            raise RuntimeError("session closing")
        got.put(data)

    feed = TruthFeed(small_plant(), put, 0.01).start()
    try:
        deadline = time.monotonic() + 10.0
        while got.qsize() < 5:
            assert time.monotonic() < deadline, "the feed stopped"
            time.sleep(0.01)
    finally:
        feed.stop()
    assert feed.errors >= 1
    assert json.loads(got.get())["position_m"][2] == 1.0


def test_daemon_publishes_the_truth_and_its_pose_sits_on_it(tmp_path: Path) -> None:
    name = f"t{uuid.uuid4().hex[:8]}"
    data: dict[str, Any] = paper_robot_data(name)
    data["bus"] = {"interface": "virtual", "channel": f"truth-test-{name}"}
    data["loop"] = {"rate_hz": 200.0, "realtime": False, "publish_every": 2}
    data["sim"] = {
        "enabled": True,
        "plant": "physical",
        "cable_ea_n": 2e5,
        "watchdog_timeout_s": 1.0,
        # the test waits for the effector to come to rest: every mode damped critically
        "cable_damping_ratio": 1.0,
        "effector_damping_n_s_per_m": 5.0,
    }
    data["faults"] = {**data["faults"], "stale_timeout_s": 0.5, "heartbeat_timeout_s": 2.0}
    for reel in data["reels"]:
        reel["cable_ea_n"] = 2e5
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    prefix = f"cablebot/{name}"
    data["zenoh"] = {"prefix": prefix, "mode": "peer", "listen": [endpoint]}
    path = tmp_path / f"{name}.toml"
    path.write_text(to_toml(data))
    proc = Proc([*CABLEBOT, "run", "--config", str(path), "--status-every", "0"], "daemon")
    session = None
    try:
        session = zenoh_session(endpoint, 30.0)
        truths: queue.Queue[dict[str, Any]] = queue.Queue()
        poses: queue.Queue[dict[str, Any]] = queue.Queue()
        session.declare_subscriber(
            f"{prefix}/{TRUTH_KEY}", lambda s: truths.put(json.loads(s.payload.to_bytes()))
        )
        session.declare_subscriber(
            f"{prefix}/pose", lambda s: poses.put(json.loads(s.payload.to_bytes()))
        )
        deadline = time.monotonic() + 30.0
        pose = None
        while pose is None or pose["state"] != "HOLDING" or pose["position_m"] is None:
            assert time.monotonic() < deadline, proc.log()
            try:
                pose = poses.get(timeout=1.0)
            except queue.Empty:
                continue
        truth = truths.get(timeout=10.0)
        assert sorted(truth) == ["position_m", "tensions_n"]
        assert len(truth["position_m"]) == 3 and len(truth["tensions_n"]) == 4
        # at rest at the power-up pose: the truth there, the pose on it (stretch modelled)
        assert math.dist(truth["position_m"], (0.0, 0.0, 2.0)) < 1e-3
        assert math.dist(pose["position_m"], truth["position_m"]) < 1e-3
        assert truth["tensions_n"] == pytest.approx([104.44] * 4, rel=0.01)
    finally:
        if session is not None:
            session.close()
        rc = proc.terminate(10.0)
        assert rc == 0, proc.log()


def test_cablebot_sim_publishes_the_truth_to_the_daemons_endpoint(tmp_path: Path) -> None:
    """`cablebot sim` with the physical plant: its peer session connects to the endpoint the
    daemon would listen on (here a stand-in session) and puts the truth there."""
    import zenoh

    name = f"s{uuid.uuid4().hex[:8]}"
    data: dict[str, Any] = paper_robot_data(name)
    data["bus"] = {"interface": "virtual", "channel": f"simtruth-{name}"}
    data["sim"] = {"enabled": False, "plant": "physical", "cable_ea_n": 2e5}
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    data["zenoh"] = {"prefix": f"cablebot/{name}", "listen": [endpoint]}
    path = tmp_path / f"{name}.toml"
    path.write_text(to_toml(data))
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    truths: queue.Queue[dict[str, Any]] = queue.Queue()
    session.declare_subscriber(
        f"cablebot/{name}/{TRUTH_KEY}", lambda s: truths.put(json.loads(s.payload.to_bytes()))
    )
    proc = Proc([*CABLEBOT, "sim", "--config", str(path)], "sim")
    try:
        truth = truths.get(timeout=30.0)
        assert math.dist(truth["position_m"], (0.0, 0.0, 2.0)) < 1e-9
        assert truth["tensions_n"] == pytest.approx([104.4422] * 4, rel=1e-5)
    finally:
        session.close()
        rc = proc.terminate(10.0)
        assert rc == 0, proc.log()
