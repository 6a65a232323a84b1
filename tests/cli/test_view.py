"""`cablebot view`: the scene it builds, the shipped layout, and the live server.

- the drawn workspace is the one `Workspace` enforces (its corners lie on the boundary);
- a Foxglove WebSocket client connected to `cablebot view` while a real daemon runs gets the
  robot (anchors = the configuration's), and scene, transform and pose messages whose positions
  are the daemon's poses (matched by their stamp), the state changes as Log messages and the
  tracking error from the status.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from controller.cli import exitcodes
from controller.cli.shape import RobotShape, ShapeError, length_colour
from controller.cli.view import (
    TOPICS,
    cable_colour,
    layout_config,
    layout_json,
    pose_scene,
    robot_scene,
    tracking_sample,
)
from controller.core.kinematics import Geometry
from controller.core.workspace import Workspace, shrink_polygon
from controller.service.config import default_config
from tests.daemon_procs import CABLEBOT, REPO, Proc, free_tcp_port
from tests.foxglove_client import FoxgloveClient, Received
from tests.live_daemon import Daemon, live_daemon, wait_holding_at_rest

foxglove = pytest.importorskip("foxglove")


# ------------------------------------------------------------------------------ pure parts


def test_drawn_workspace_is_the_enforced_one() -> None:
    cfg = default_config()
    shape = RobotShape.from_summary(cfg.summary())
    limits = Workspace.from_limits(cfg.limits, Geometry(cfg.anchors_m))
    assert shape.anchors_m == cfg.anchors_m
    assert len(shape.workspace_m) == len(shape.footprint_m) == 4
    assert (shape.floor_z_m, shape.top_z_m) == (limits.floor_z_m, limits.top_z_m)
    cx = sum(x for x, _ in shape.workspace_m) / 4
    cy = sum(y for _, y in shape.workspace_m) / 4
    for x, y in shape.workspace_m:
        for z in (shape.floor_z_m, shape.top_z_m):
            assert limits.check_point((x, y, z)) is None  # on the boundary: allowed
            out = (x + 1e-3 * (x - cx), y + 1e-3 * (y - cy), z)
            assert limits.check_point(out) is not None  # just outside: refused
    # the paper robot: 80.9 m x 50 m, 2 m margin
    xs = sorted(x for x, _ in shape.workspace_m)
    assert xs[0] == pytest.approx(-40.45 + 2.0) and xs[-1] == pytest.approx(40.45 - 2.0)


def test_drawn_workspace_of_a_hangprinter_is_its_true_shape() -> None:
    """Among the anchors the scene draws the solid itself (the hull's faces moved in, cut by
    floor, top and print radius), not a prism of its outline: every drawn corner is in the
    enforced workspace (to a micrometre) and some lie between floor and top."""
    from controller.cli.configs import find_example
    from controller.service.config import load_config

    cfg = load_config(find_example("hangprinter-v4.toml"))
    shape = RobotShape.from_summary(cfg.summary())
    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    scene = _decode_scene(robot_scene(shape, 1))
    line = {e["id"]: e for e in scene["entities"]}["workspace"]["lines"][0]
    pts = [(q["x"], q["y"], q["z"]) for q in line["points"]]
    assert len(pts) >= 2 * 12 and len(pts) % 2 == 0
    mid = [sum(p[k] for p in pts) / len(pts) for k in range(3)]
    for p in pts:
        d = math.dist(p, mid)
        inward = [p[k] + 1e-6 * (mid[k] - p[k]) / d for k in range(3)]
        assert ws.check_point(inward) is None, p
    assert any(ws.floor_z_m + 0.01 < p[2] < ws.top_z_m - 0.01 for p in pts)
    # the apex region: nothing drawn at the top height as wide as the outline seen from above
    top = [p for p in pts if abs(p[2] - ws.top_z_m) < 1e-9]
    assert max(math.hypot(p[0], p[1]) for p in top) < 0.5 * max(
        math.hypot(x, y) for x, y in shape.workspace_m
    )


def test_shrink_polygon_square_and_errors() -> None:
    sq = ((0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0))
    out = shrink_polygon(sq, 0.5)
    assert [tuple(round(c, 12) for c in p) for p in out] == [
        (0.5, 0.5),
        (1.5, 0.5),
        (1.5, 1.5),
        (0.5, 1.5),
    ]
    assert shrink_polygon(sq, 1.0) in ((), ((1.0, 1.0),))  # nothing, or a point, is left
    assert shrink_polygon(sq, 1.5) == ()
    with pytest.raises(ShapeError, match="leaves no workspace"):
        RobotShape.from_summary(
            {
                **default_config().summary(),
                "limits": {**default_config().summary()["limits"], "xy_margin_m": 30.0},
            }
        )
    with pytest.raises(ShapeError, match="finite"):
        RobotShape.from_summary(
            {
                **default_config().summary(),
                "limits": {**default_config().summary()["limits"], "floor_z_m": "nan"},
            }
        )
    with pytest.raises(ShapeError):
        RobotShape.from_summary({"reels": [{"anchor_m": [0, 0, 1]}], "limits": {}})
    with pytest.raises(ShapeError):
        RobotShape.from_summary({"name": "x"})


def test_cable_colour_by_length_and_tension_hook() -> None:
    shape = RobotShape.from_summary(default_config().summary())
    lo, hi = shape.min_cable_m, shape.max_cable_m
    assert cable_colour(lo, shape) == (0.0, 0.0, 1.0)
    assert cable_colour(hi, shape) == (1.0, 0.0, 0.0)
    assert cable_colour((lo + hi) / 2, shape) == (0.0, 1.0, 0.0)
    assert cable_colour(hi * 10, shape) == (1.0, 0.0, 0.0)  # clamped
    assert cable_colour(40.0, shape, tension_n=100.0) == cable_colour(40.0, shape)
    assert length_colour(math.nan, 0.0, 1.0) == (0.0, 1.0, 0.0)


def _decode_scene(update: Any) -> dict[str, Any]:
    """Decode a SceneUpdate through its own protobuf schema, as the Foxglove app does."""
    from tests.foxglove_client import _decoder

    schema = update.get_schema()
    import base64

    channel = {
        "encoding": "protobuf",
        "schema": base64.b64encode(schema.data).decode(),
        "schemaName": schema.name,
    }
    out: dict[str, Any] = _decoder(channel)(update.encode())
    return out


def test_pose_scene_never_draws_a_stale_effector() -> None:
    shape = RobotShape.from_summary(default_config().summary())
    pose = {
        "seq": 1,
        "stamp_ns": 1_700_000_000_123_456_789,
        "position_m": [1.0, 2.0, 3.0],
        "cable_lengths_m": [40.0, 41.0, 42.0, 43.0],
        "residual_m": 1e-6,
        "valid": True,
        "state": "HOLDING",
    }
    scene = _decode_scene(pose_scene(shape, pose, [1.0, 2.0, 3.5], [(0, 0, 2), (1, 2, 3)], 5))
    ids = {e["id"]: e for e in scene["entities"]}
    assert set(ids) == {"effector", "cables", "setpoint", "trail"}
    p = ids["effector"]["spheres"][0]["pose"]["position"]
    assert (p["x"], p["y"], p["z"]) == (1.0, 2.0, 3.0)
    assert len(ids["cables"]["lines"]) == 4
    assert ids["cables"]["texts"][2]["text"] == "L3 42.000 m"
    end = ids["cables"]["lines"][0]["points"]
    assert end[0] == {"x": -40.45, "y": -25.0, "z": 7.62} and end[1] == {
        "x": 1.0,
        "y": 2.0,
        "z": 3.0,
    }
    assert scene["deletions"] == []
    invalid = {**pose, "valid": False, "position_m": None}
    scene = _decode_scene(pose_scene(shape, invalid, None, [], 5))
    assert scene["entities"] == []
    assert {d["id"] for d in scene["deletions"]} == {"effector", "cables", "setpoint"}


def test_robot_scene_has_anchors_footprint_workspace() -> None:
    shape = RobotShape.from_summary(default_config().summary())
    scene = _decode_scene(robot_scene(shape, 1))
    ids = {e["id"]: e for e in scene["entities"]}
    assert set(ids) == {"anchors", "footprint", "workspace"}
    got = [tuple(s["pose"]["position"][k] for k in "xyz") for s in ids["anchors"]["spheres"]]
    assert got == list(shape.anchors_m)
    assert [t["text"] for t in ids["anchors"]["texts"]] == ["B1", "B2", "B3", "B4"]
    assert len(ids["workspace"]["lines"][0]["points"]) == 6 * 4  # 4 edges x (floor, top, post)


def test_tracking_sample() -> None:
    st = {
        "state": "MOVING",
        "pose": {"position_m": [0.0, 0.0, 2.0], "residual_m": 2e-6},
        "setpoint_m": [0.003, 0.004, 2.0],
    }
    t = tracking_sample(st)
    assert t["error_m"] == pytest.approx(0.005) and t["error_mm"] == pytest.approx(5.0)
    assert t["residual_mm"] == pytest.approx(0.002)
    assert tracking_sample({"pose": {}, "setpoint_m": None})["error_m"] is None


def test_geometry_comes_from_the_status_and_the_config_file_is_the_fallback() -> None:
    from controller.cli.view import LiveView
    from controller.service.config import paper_robot_data, parse_config

    file_shape = RobotShape.from_summary(default_config().summary())
    view = LiveView(foxglove.Context(), prefix="cablebot/t", fallback_shape=file_shape)
    assert view.shape is file_shape
    view.on_status(json.dumps({"state": "HOLDING", "setpoint_m": [0.0, 0.0, 2.0]}).encode())
    assert view.shape is file_shape  # the status carries no configuration: the file's
    assert view.setpoint_m == [0.0, 0.0, 2.0]
    data = paper_robot_data("other")
    data["reels"][0]["anchor_m"] = [-30.0, -20.0, 7.62]
    other = parse_config(data, "test").summary()
    view.on_status(json.dumps({"state": "HOLDING", "setpoint_m": None, "config": other}).encode())
    assert view.shape is not None and view.shape.anchors_m[0] == (-30.0, -20.0, 7.62)
    assert view.setpoint_m is None
    view.on_status(b"not json")  # ignored
    view.on_pose(b'{"no": "stamp"}')  # ignored
    assert view.poses == 0 and view.shape.anchors_m[0] == (-30.0, -20.0, 7.62)


def test_shipped_layout_is_current_and_names_the_view_topics() -> None:
    text = (REPO / "docs" / "foxglove-layout.json").read_text()
    assert text == layout_json(), "regenerate docs/foxglove-layout.json from layout_config()"
    layout = json.loads(text)
    ids = set(layout["configById"])
    assert {"3D!cablebot", "Plot!x", "Plot!y", "Plot!z", "Log!state"} <= ids

    def leaves(node: Any) -> Iterator[str]:
        if isinstance(node, str):
            yield node
        elif isinstance(node, dict):
            for key in ("first", "second"):
                yield from leaves(node[key])

    used = set(leaves(layout["layout"]))
    for tab in layout["configById"]["Tab!side"]["tabs"]:
        used |= set(leaves(tab["layout"]))
    assert used == ids  # every panel is placed, none is missing
    topics = set(TOPICS.values())
    for panel in layout_config()["configById"].values():
        for path in panel.get("paths", []):
            assert path["value"].split(".", 1)[0] in topics, path
    assert set(layout["configById"]["3D!cablebot"]["topics"]) == {"/robot", "/scene"}


# ------------------------------------------------------------------------------ live


@pytest.fixture(scope="module")
def robot(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Daemon, Path]]:
    with live_daemon(tmp_path_factory.mktemp("view")) as d:
        yield d


def _start_view(d: Daemon) -> tuple[Proc, str]:
    proc = Proc(
        [
            *CABLEBOT,
            "view",
            "--connect",
            d.endpoint,
            "--prefix",
            d.prefix,
            "--port",
            "0",
            "--status-hz",
            "10",
        ],
        "view",
    )
    line = proc.wait_line("Foxglove WebSocket server on", 30.0)
    m = re.search(r"ws://[0-9.]+:\d+", line)
    assert m is not None, line
    return proc, m.group(0)


def _collect(c: FoxgloveClient, seconds: float) -> list[Received]:
    out: list[Received] = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        m = c.next_message(max(0.01, deadline - time.monotonic()))
        if m is not None:
            out.append(m)
    return out


@pytest.mark.slow
def test_view_serves_the_live_robot_over_the_foxglove_protocol(
    robot: tuple[Daemon, Path],
) -> None:
    d, cfg_path = robot
    wait_holding_at_rest(d)
    # every pose the daemon publishes, as a separate Zenoh subscriber sees it, by seq
    published: dict[int, dict[str, Any]] = {}

    def on_pose(s: Any) -> None:
        p = json.loads(s.payload.to_bytes())
        published[p["seq"]] = p

    sub = d.session.declare_subscriber(f"{d.prefix}/pose", on_pose)

    def drawn_from(stamp_ns: int) -> dict[str, Any]:
        """The pose a scene or transform stamped `stamp_ns` was drawn from. Ticks without a
        new encoder reading repeat the stamp, and then also the lengths and the position."""
        refs = [p for p in list(published.values()) if p["stamp_ns"] == stamp_ns]
        assert refs, f"no published pose has the stamp {stamp_ns}"
        assert all(r["position_m"] == refs[0]["position_m"] for r in refs), refs
        return refs[0]

    proc, url = _start_view(d)
    client = None
    try:
        client = FoxgloveClient(url)
        assert client.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1")
        client.wait_topics(list(TOPICS.values()), 20.0)
        schemas = {t: (c["encoding"], c["schemaName"]) for t, c in client.channels.items()}
        assert schemas[TOPICS["scene"]] == ("protobuf", "foxglove.SceneUpdate")
        assert schemas[TOPICS["robot"]] == ("protobuf", "foxglove.SceneUpdate")
        assert schemas[TOPICS["tf"]] == ("protobuf", "foxglove.FrameTransform")
        assert schemas[TOPICS["state"]] == ("protobuf", "foxglove.Log")
        assert schemas[TOPICS["pose"]] == ("json", "cablebot.Pose")
        for topic in TOPICS.values():
            client.subscribe(topic)

        # the robot: the anchors of the daemon's configuration (from its status)
        got = _collect(client, 2.0)
        robots = [m for m in got if m.topic == TOPICS["robot"]]
        assert robots, "no /robot message after subscribing"
        anchors = next(e for e in robots[-1].message["entities"] if e["id"] == "anchors")
        drawn = [tuple(s["pose"]["position"][k] for k in "xyz") for s in anchors["spheres"]]
        from controller.service.config import load_config

        assert drawn == list(load_config(cfg_path).anchors_m)
        states = [m.message for m in got if m.topic == TOPICS["state"]]
        assert states and states[-1]["message"].startswith("HOLDING"), states

        # a move: scene, transform and pose messages carry the daemon's positions
        start = d.status()["pose"]["position_m"]
        target = [start[0] + 0.4, start[1] - 0.2, start[2] + 0.1]
        kind, reply = d.query(
            "cmd/move", json.dumps({"position_m": target, "speed_mps": 0.5}).encode()
        )
        assert kind == "ok", reply
        got = _collect(client, 2.5)
        scenes = [m for m in got if m.topic == TOPICS["scene"]]
        tfs = [m for m in got if m.topic == TOPICS["tf"]]
        poses = [m for m in got if m.topic == TOPICS["pose"]]
        assert len(scenes) >= 20 and len(tfs) >= 20 and len(poses) >= 100, (
            len(scenes),
            len(tfs),
            len(poses),
        )
        moved = 0
        for m in scenes:
            eff = next(e for e in m.message["entities"] if e["id"] == "effector")
            p = eff["spheres"][0]["pose"]["position"]
            ref = drawn_from(m.log_time_ns)
            assert [p["x"], p["y"], p["z"]] == ref["position_m"]
            cables = next(e for e in m.message["entities"] if e["id"] == "cables")
            assert [float(t["text"].split()[1]) for t in cables["texts"]] == pytest.approx(
                ref["cable_lengths_m"], abs=6e-4
            )
            moved += math.dist(ref["position_m"], start) > 1e-3
        assert moved >= 10, "the scene did not follow the move"
        for m in tfs:
            tr = m.message["translation"]
            assert [tr["x"], tr["y"], tr["z"]] == drawn_from(m.log_time_ns)["position_m"]
            assert (m.message["parent_frame_id"], m.message["child_frame_id"]) == (
                "world",
                "effector",
            )
        for m in poses:
            assert m.message == published[m.message["seq"]]
        seqs = [m.message["seq"] for m in poses]
        assert seqs == sorted(seqs)
        tracking = [m.message for m in got if m.topic == TOPICS["tracking"]]
        assert len(tracking) >= 10
        moving = [t for t in tracking if t["state"] == "MOVING"]
        assert moving and all(t["error_m"] is not None for t in moving)

        # state changes become Log messages with their level
        wait_holding_at_rest(d)
        assert d.query("cmd/disarm")[0] == "ok"
        assert d.query("cmd/arm")[0] == "ok"
        got = _collect(client, 2.0)
        logs = [m.message for m in got if m.topic == TOPICS["state"]]
        texts = [lg["message"].split(":")[0] for lg in logs]
        assert texts[:3] == ["DISARMED", "ARMING", "HOLDING"], logs
        assert all(lg["level"] == "INFO" and lg["name"] == d.prefix for lg in logs[:3])
    finally:
        if client is not None:
            client.close()
        sub.undeclare()
        rc = proc.terminate(10.0)
    assert rc == 0, proc.log()


@pytest.mark.slow
def test_view_without_daemon_exits_no_daemon(tmp_path: Path) -> None:
    r = subprocess.run(
        [*CABLEBOT, "view", "--connect", f"tcp/127.0.0.1:{free_tcp_port()}", "--port", "0"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert r.returncode == exitcodes.NO_DAEMON, r.stdout + r.stderr
    assert "no cablebot daemon answered" in r.stderr
