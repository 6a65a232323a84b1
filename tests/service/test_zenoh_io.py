"""The Zenoh interface against a fake controller: queryables, publishers, set-points, config."""

from __future__ import annotations

import json
import queue
import shutil
import subprocess
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import zenoh

from controller.cli import exitcodes
from controller.core.commands import (
    MAX_JSON_DEPTH,
    MAX_PAYLOAD_BYTES,
    QUOTE_CHARS,
    VERBS,
    Move,
    Setpoint,
)
from controller.core.commands import Path as PathCmd
from controller.service import zenoh_io
from controller.service.zenoh_io import free_tcp_port
from tests.fakes_zenoh import FakeController, FakePose, ZCfg


def _strict(data: bytes) -> Any:
    def bad(name: str) -> Any:
        raise AssertionError(f"non-finite {name} in JSON")

    return json.loads(data, parse_constant=bad)


class Rig:
    """A daemon-side interface with a fake controller, and a client session to it."""

    def __init__(self, fake: FakeController, iface: zenoh_io.ZenohInterface, client: Any) -> None:
        self.fake = fake
        self.iface = iface
        self.client = client
        self.prefix = iface.prefix

    def get(self, suffix: str, payload: bytes | None = None, timeout: float = 5.0) -> Any:
        """One query; returns ("ok", json) or ("err", json-or-text)."""
        replies = list(self.client.get(f"{self.prefix}/{suffix}", payload=payload, timeout=timeout))
        assert len(replies) == 1, replies
        r = replies[0]
        if r.ok is not None:
            assert r.ok.encoding == zenoh.Encoding.APPLICATION_JSON
            return "ok", _strict(r.ok.payload.to_bytes())
        raw = r.err.payload.to_bytes()
        try:
            return "err", _strict(raw)
        except ValueError:
            return "err", raw.decode()

    def subscribe(self, suffix: str) -> queue.Queue[bytes]:
        q: queue.Queue[bytes] = queue.Queue()
        self.client.declare_subscriber(
            f"{self.prefix}/{suffix}", lambda s: q.put(s.payload.to_bytes())
        )
        return q


@pytest.fixture
def rig() -> Iterator[Rig]:
    port = free_tcp_port()
    fake = FakeController(rate_hz=100.0)
    iface = zenoh_io.ZenohInterface(
        ZCfg(listen=(f"tcp/127.0.0.1:{port}",)), fake, reply_timeout_s=1.0
    )
    iface.open()
    fake.publisher = iface
    fake.start()
    client = zenoh.open(zenoh_io.client_config([f"tcp/127.0.0.1:{port}"]))
    try:
        yield Rig(fake, iface, client)
    finally:
        client.close()  # type: ignore[no-untyped-call]
        fake.stop()
        iface.close()


def _wait(cond: Any, timeout_s: float = 3.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.01)


# ------------------------------------------------------------------------------ config


def test_session_config_defaults_are_local_peer_without_scouting() -> None:
    conf = zenoh_io.session_config(None)
    assert json.loads(conf.get_json("mode")) == "peer"
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7447"]
    assert json.loads(conf.get_json("connect/endpoints")) == []
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False


def test_session_config_fields_and_file_override(tmp_path: Path) -> None:
    cfg = ZCfg(mode="client", listen=(), connect=("tcp/10.0.0.1:7447",))
    conf = zenoh_io.session_config(cfg)
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/10.0.0.1:7447"]
    f = tmp_path / "z.json5"
    f.write_text('{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:17447"] }, // c\n}')
    conf = zenoh_io.session_config(
        ZCfg(mode="client", listen=("tcp/127.0.0.1:1",), config_file=str(f))
    )
    assert json.loads(conf.get_json("mode")) == "peer"  # the file wins
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:17447"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False  # filled in


def test_example_tls_acl_file_is_a_valid_zenoh_config() -> None:
    path = Path(__file__).resolve().parents[2] / "docs" / "zenoh-tls-acl.json5"
    conf = zenoh.Config.from_file(str(path))
    assert json.loads(conf.get_json("access_control/enabled")) is True
    assert json.loads(conf.get_json("access_control/default_permission")) == "deny"
    assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True


def test_dumps_never_writes_nan() -> None:
    data = zenoh_io.dumps({"a": float("nan"), "b": [1.0, float("inf")], "c": (1, "x")})
    assert _strict(data) == {"a": None, "b": [1.0, None], "c": [1, "x"]}


# ------------------------------------------------------------------------------ queryables


def test_status_carries_controller_status_and_put_statistics(rig: Rig) -> None:
    _wait(lambda: rig.iface.poses_published > 20)
    kind, st = rig.get("status")
    assert kind == "ok"
    assert st["state"] == "DISARMED"
    assert st["loop"]["jitter_p99_s"] is None  # NaN became null
    z = st["zenoh"]
    assert z["prefix"] == "cablebot/test"
    assert z["poses_published"] > 20
    assert z["pose_put"]["p50_us"] > 0.0


def test_commands_ok_and_refused(rig: Rig) -> None:
    assert rig.get("cmd/move", b'{"position_m": [0, 0, 1]}') == (
        "err",
        {"error": "not allowed in DISARMED (needs HOLDING/MOVING)"},
    )
    assert rig.get("cmd/arm") == ("ok", {"ok": True, "state": "HOLDING"})
    kind, reply = rig.get("cmd/move", b'{"position_m": [0.1, 0, 2], "speed_mps": 1.0}')
    assert (kind, reply["ok"]) == ("ok", True)
    _wait(lambda: rig.fake.state == "HOLDING" and rig.fake.position_m == (0.1, 0.0, 2.0))
    assert rig.get("cmd/estop") == ("ok", {"ok": True, "state": "ESTOPPED"})
    assert rig.get("cmd/reset") == ("ok", {"ok": True, "state": "DISARMED"})
    assert rig.iface.stats()["commands"]["ok"] == 4
    assert rig.iface.stats()["commands"]["refused"] == 1


@pytest.mark.parametrize(
    ("verb", "payload", "reason"),
    [
        ("move", b"{not json", "malformed JSON"),
        ("move", b"[1, 2, 3]", "expected a JSON object"),
        ("move", b"{}", "missing field(s): position_m"),
        ("move", b'{"position_m": [0, 0, 1], "sped": 1}', "unknown field(s): sped"),
        ("move", b'{"position_m": [NaN, 0, 1]}', "non-finite number NaN"),
        ("move", b'{"position_m": ["NaN", 0, 1]}', "position_m[0]: expected a number"),
        ("move", b'{"position_m": [0, 0, Infinity]}', "non-finite number Infinity"),
        ("move", b'{"position_m": [0, 0]}', "position_m: expected [x, y, z]"),
        ("move", b'{"position_m": [0, 0, 1], "speed_mps": -1}', "speed_mps: must be > 0"),
        ("move", b'{"position_m": [5, 0, 1]}', "outside the workspace"),
        ("path", b'{"points_m": []}', "points_m: expected a non-empty list"),
        ("path", b'{"points_m": [[0, 0, 1], [0, 9, 1]]}', "points_m[1]: outside the workspace"),
        ("home", b'{"position_m": [0, 0, true]}', "position_m[2]: expected a number"),
        ("arm", b'{"now": true}', "unknown field(s): now"),
    ],
)
def test_malformed_and_out_of_workspace_commands_change_nothing(
    rig: Rig, verb: str, payload: bytes, reason: str
) -> None:
    before = (rig.fake.state, rig.fake.position_m)
    kind, body = rig.get(f"cmd/{verb}", payload)
    assert kind == "err"
    assert reason in body["error"]
    assert rig.fake.submitted == []  # rejected on the Zenoh thread, the loop never saw it
    assert (rig.fake.state, rig.fake.position_m) == before


def test_wildcard_command_query_is_refused(rig: Rig) -> None:
    replies = list(rig.client.get(f"{rig.prefix}/cmd/*", timeout=3.0))
    assert len(replies) == len(VERBS)  # one per verb, all errors
    for r in replies:
        assert r.err is not None
        assert "wildcard" in json.loads(r.err.payload.to_bytes())["error"]
    assert rig.fake.submitted == []
    assert rig.fake.state == "DISARMED"


def _raw_err(rig: Rig, suffix: str, payload: bytes) -> bytes:
    replies = list(rig.client.get(f"{rig.prefix}/{suffix}", payload=payload, timeout=10.0))
    assert len(replies) == 1
    assert replies[0].err is not None
    raw: bytes = replies[0].err.payload.to_bytes()
    return raw


def test_an_oversized_command_is_refused_by_its_size_and_not_echoed(rig: Rig) -> None:
    # 10 MB: 2.6 million numbers, as a hostile client sent them
    big = b'{"position_m": [' + b"1.0, " * 2_600_000 + b"1.0]}"
    raw = _raw_err(rig, "cmd/move", big)
    assert _strict(raw) == {
        "error": f"payload too large: {len(big)} bytes, move takes at most "
        f"{MAX_PAYLOAD_BYTES['move']}"
    }
    raw = _raw_err(rig, "cmd/path", b"[" * (MAX_PAYLOAD_BYTES["path"] + 1))
    assert b"payload too large" in raw
    assert rig.iface.stats()["commands"]["malformed"] == 2
    assert rig.fake.submitted == []


@pytest.mark.parametrize(
    ("verb", "payload"),
    [
        ("move", b'{"position_m": [' + b"1.0, " * 800 + b"1.0]}"),
        ("move", b'{"position_m": "' + b"x" * 4000 + b'"}'),
        ("path", b'{"points_m": [[0, 0, 1], [' + b"7, " * 40_000 + b"7]]}"),
        ("path", b'{"' + b"y" * 100_000 + b'": 1}'),
        ("home", b'{"position_m": [0, 0, 1], "' + rb"\u0000" * 600 + b'": 1}'),
    ],
)
def test_a_refusal_quotes_at_most_a_short_prefix(
    rig: Rig, verb: str, payload: bytes, caplog: pytest.LogCaptureFixture
) -> None:
    assert len(payload) <= MAX_PAYLOAD_BYTES[verb]
    raw = _raw_err(rig, f"cmd/{verb}", payload)
    assert len(raw) <= 80 + QUOTE_CHARS, raw
    assert all(len(r.getMessage()) <= 400 for r in caplog.records)
    assert rig.iface.stats()["commands"]["malformed"] == 1


@pytest.mark.parametrize("verb", ["move", "path", "estop"])
def test_deep_nesting_is_malformed_and_logs_no_traceback(
    rig: Rig, verb: str, caplog: pytest.LogCaptureFixture
) -> None:
    depth = min(1200, MAX_PAYLOAD_BYTES[verb] // 2 - 10)
    payload = b"[" * depth + b"]" * depth
    for _ in range(3):
        assert rig.get(f"cmd/{verb}", payload) == (
            "err",
            {"error": f"nested too deeply: at most {MAX_JSON_DEPTH} levels of [ and {{"},
        )
    assert rig.iface.stats()["commands"]["malformed"] == 3
    assert [r for r in caplog.records if r.exc_info or r.levelname == "ERROR"] == []
    assert rig.fake.submitted == []


def test_reply_reasons_are_cut_to_a_bounded_length() -> None:
    body = _strict(zenoh_io.error_payload("z" * 100_000))
    assert len(body["error"]) == zenoh_io.MAX_REASON_CHARS
    assert body["error"].endswith("...")


def test_reply_timeout_when_the_loop_does_not_answer(rig: Rig) -> None:
    rig.fake.hang = True
    t0 = time.monotonic()
    kind, body = rig.get("cmd/stop")
    assert kind == "err"
    assert body == {"error": "timeout: the control loop did not answer; command cancelled"}
    assert 0.9 <= time.monotonic() - t0 < 3.0
    assert rig.iface.stats()["commands"]["timeout"] == 1


def test_a_timed_out_command_is_cancelled_and_never_runs(rig: Rig) -> None:
    rig.fake.paused = True
    kind, body = rig.get("cmd/arm")
    assert kind == "err"
    assert body == {"error": "timeout: the control loop did not answer; command cancelled"}
    rig.fake.paused = False
    time.sleep(0.2)  # many ticks
    assert rig.fake.state == "DISARMED"
    assert rig.get("cmd/arm") == ("ok", {"ok": True, "state": "HOLDING"})


def test_a_waiting_command_does_not_delay_estop(rig: Rig) -> None:
    rig.fake.hang = True
    import threading

    slow = threading.Thread(target=rig.get, args=("cmd/stop",))
    slow.start()
    time.sleep(0.1)
    rig.fake.hang = False
    t0 = time.monotonic()
    kind, _ = rig.get("cmd/estop")
    assert kind == "ok"
    assert time.monotonic() - t0 < 0.5
    slow.join()


# ------------------------------------------------------------------------------ publishers


def test_pose_and_state_are_published(rig: Rig) -> None:
    poses = rig.subscribe("pose")
    states = rig.subscribe("state")
    time.sleep(0.3)  # let the subscription propagate
    sample = _strict(poses.get(timeout=3.0))
    assert set(sample) == {
        "seq",
        "stamp_ns",
        "position_m",
        "cable_lengths_m",
        "residual_m",
        "valid",
        "state",
    }
    assert sample["state"] == "DISARMED"
    rig.get("cmd/arm")
    st = _strict(states.get(timeout=3.0))
    assert st["state"] == "HOLDING"
    assert st["reason"] is None
    assert abs(st["stamp_ns"] - time.time_ns()) < 5e9


@pytest.mark.parametrize("threaded", [True, False])
def test_both_publish_modes_deliver_poses_and_every_state_in_order(threaded: bool) -> None:
    port = free_tcp_port()
    fake = FakeController()
    iface = zenoh_io.ZenohInterface(
        ZCfg(listen=(f"tcp/127.0.0.1:{port}",)), fake, publish_thread=threaded
    )
    iface.open()
    client = zenoh.open(zenoh_io.client_config([f"tcp/127.0.0.1:{port}"]))
    try:
        got: queue.Queue[tuple[str, bytes]] = queue.Queue()

        def collector(what: str) -> Any:
            return lambda s: got.put((what, s.payload.to_bytes()))

        for what in ("pose", "state"):
            client.declare_subscriber(f"cablebot/test/{what}", collector(what))
        time.sleep(0.3)
        for i in range(1, 6):
            iface.publish_state(f"S{i}", None if i % 2 else "why", i)
            iface.publish_pose(FakePose(i, time.time_ns(), (0.0, 0.0, float(i)), "HOLDING"))
            time.sleep(0.02)
        rx = [got.get(timeout=3.0) for _ in range(10)]
        states = [_strict(d) for w, d in rx if w == "state"]
        assert [s["state"] for s in states] == ["S1", "S2", "S3", "S4", "S5"]
        assert [s["reason"] for s in states] == [None, "why", None, "why", None]
        assert [s["stamp_ns"] for s in states] == [1, 2, 3, 4, 5]
        assert [_strict(d)["seq"] for w, d in rx if w == "pose"] == [1, 2, 3, 4, 5]
        st = iface.stats()
        assert st["publish_thread"] is threaded
        assert st["poses_published"] == 5
        assert st["states_published"] == 5
        assert st["pose_publish_tick"]["p50_us"] > 0.0
    finally:
        client.close()  # type: ignore[no-untyped-call]
        iface.close()


def test_liveliness_token_while_open(rig: Rig) -> None:
    alive = list(rig.client.liveliness().get(f"{rig.prefix}/alive", timeout=2.0))
    assert [str(r.ok.key_expr) for r in alive if r.ok is not None] == [f"{rig.prefix}/alive"]


# ------------------------------------------------------------------------------ set-points


def test_setpoints_good_and_bad(rig: Rig, caplog: pytest.LogCaptureFixture) -> None:
    pub = rig.client.declare_publisher(f"{rig.prefix}/setpoint")
    time.sleep(0.3)
    pub.put(b'{"position_m": [0.1, 0.2, 1.5]}')
    for bad in (b"{", b'{"position_m": [NaN, 0, 1]}', b'{"position": [0, 0, 1]}', b"[]"):
        pub.put(bad)
    pub.put(b'{"position_m": [0.3, 0.2, 1.5]}')
    _wait(lambda: rig.iface.setpoints_ok + rig.iface.setpoints_bad == 6)
    assert rig.fake.setpoints == [(0.1, 0.2, 1.5), (0.3, 0.2, 1.5)]
    assert rig.iface.setpoints_bad == 4
    # logged at most once per second, not once per bad sample
    assert sum("bad set-point" in r.getMessage() for r in caplog.records) <= 2


@pytest.mark.parametrize("key", ["cablebot/test/*", "cablebot/test/**", "cablebot/**", "**"])
def test_a_wildcard_put_is_never_taken_as_a_setpoint(rig: Rig, key: str) -> None:
    rig.client.put(key, b'{"position_m": [1.5, 1, 2]}')
    rig.client.put(f"{rig.prefix}/setpoint", b'{"position_m": [0.1, 0.2, 1.5]}')  # exact key
    _wait(lambda: rig.iface.setpoints_ok + rig.iface.setpoints_bad == 2)
    assert rig.fake.setpoints == [(0.1, 0.2, 1.5)]
    assert rig.iface.setpoints_bad == 1


def test_bad_setpoints_are_refused_by_size_and_logged_briefly(
    rig: Rig, caplog: pytest.LogCaptureFixture
) -> None:
    pub = rig.client.declare_publisher(f"{rig.prefix}/setpoint")
    time.sleep(0.3)
    long_list = b'{"position_m": [' + b"1.0, " * 800 + b"1.0]}"
    assert len(long_list) <= MAX_PAYLOAD_BYTES["setpoint"]
    pub.put(long_list)  # logged: at most a short prefix of it
    pub.put(b'{"position_m": [' + b"1.0, " * 2_600_000 + b"1.0]}")  # 13 MB: refused by size
    pub.put(b'{"position_m": [0.3, 0.2, 1.5]}')
    _wait(lambda: rig.iface.setpoints_ok + rig.iface.setpoints_bad == 3, 10.0)
    assert rig.fake.setpoints == [(0.3, 0.2, 1.5)]
    assert rig.iface.setpoints_bad == 2
    messages = [r.getMessage() for r in caplog.records if "bad set-point" in r.getMessage()]
    assert messages
    assert all(len(m) <= 300 for m in messages), [m[:300] for m in messages]


def test_open_fails_cleanly_when_the_port_is_taken() -> None:
    port = free_tcp_port()
    fake = FakeController()
    first = zenoh_io.ZenohInterface(ZCfg(listen=(f"tcp/127.0.0.1:{port}",)), fake)
    first.open()
    try:
        second = zenoh_io.ZenohInterface(ZCfg(listen=(f"tcp/127.0.0.1:{port}",)), fake)
        with pytest.raises(zenoh.ZError):
            second.open()
        assert second.session is None
    finally:
        first.close()


def test_precheck_asks_the_workspace_once_per_move_or_path() -> None:
    fake = FakeController()
    iface = zenoh_io.ZenohInterface(ZCfg(), fake)
    assert iface._precheck(Move((0.0, 0.0, 1.0))) is None
    assert "outside" in str(iface._precheck(Move((0.0, 0.0, 9.0))))
    path = PathCmd(((0.0, 0.0, 1.0), (0.0, 0.5, 1.0), (0.0, 9.0, 1.0), (0.0, 0.0, 9.0)))
    assert iface._precheck(path) == "points_m[2]: outside the workspace: y=9.0 not in [-1.0, 1.0]"
    assert iface._precheck(Setpoint((0.0, 0.0, 9.0))) is None  # streamed: the loop limits it
    assert fake.workspace.calls == 3  # one call per move or path, not one per point


def test_precheck_with_the_robots_workspace() -> None:
    import math
    from types import SimpleNamespace

    from controller.core.workspace import Workspace
    from controller.service.config import default_config

    cfg = default_config()
    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    iface = zenoh_io.ZenohInterface(ZCfg(), SimpleNamespace(workspace=ws))
    a = 2.0 * math.pi / 1000
    pts = [(10.0 * math.cos(i * a), 10.0 * math.sin(i * a), 2.0) for i in range(1000)]
    assert iface._precheck(PathCmd(tuple(pts))) is None
    pts[700] = (39.0, 0.0, 2.0)
    pts[800] = (0.0, 0.0, -1.0)
    why = ws.check_target(pts[700])
    assert why is not None and "plan-view polygon" in why
    assert iface._precheck(PathCmd(tuple(pts))) == f"points_m[700]: {why}"
    assert iface._precheck(Move((0.0, 0.0, 9.0))) == ws.check_target((0.0, 0.0, 9.0))
    # Points only: both ends allowed, the leg between them is the controller's to judge.
    tight = Workspace.from_limits(replace(cfg.limits, min_cable_m=6.0), cfg.geometry)
    corner = cfg.geometry.footprint_m[0]
    ends = ((corner[0] + 6.0, corner[1] + 2.0, 6.0), (corner[0] + 2.0, corner[1] + 6.0, 6.0))
    assert tight.check_target(ends[0]) is None and tight.check_target(ends[1]) is None
    assert tight.check_path(list(ends)) is not None  # the leg passes under the anchor
    iface = zenoh_io.ZenohInterface(ZCfg(), SimpleNamespace(workspace=tight))
    assert iface._precheck(PathCmd(ends)) is None


# ------------------------------------------------------------------------------ TLS + ACL


def _openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


def _make_pki(d: Path) -> None:
    """A CA, a server certificate for localhost, and client certificates (X.509 v3)."""
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes"]
    _openssl("req", "-x509", *ec, "-days", "2", "-subj", "/CN=test-ca", "-keyout", "ca.key",
             "-out", "ca.pem", cwd=d)  # fmt: skip
    (d / "server.ext").write_text("basicConstraints=CA:FALSE\nsubjectAltName=DNS:localhost\n")
    (d / "client.ext").write_text("basicConstraints=CA:FALSE\nextendedKeyUsage=clientAuth\n")
    for name, cn, ext in (
        ("server", "localhost", "server.ext"),
        ("operator", "cablebot-operator", "client.ext"),
        ("viewer", "viewer", "client.ext"),
    ):
        _openssl("req", *ec, "-subj", f"/CN={cn}", "-keyout", f"{name}.key", "-out",
                 f"{name}.csr", cwd=d)  # fmt: skip
        _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
                 "-CAcreateserial", "-days", "2", "-extfile", ext, "-out", f"{name}.pem",
                 cwd=d)  # fmt: skip


def _client_file(d: Path, name: str | None) -> str:
    tls: dict[str, Any] = {"root_ca_certificate": str(d / "ca.pem")}
    if name is not None:
        tls |= {
            "enable_mtls": True,
            "connect_private_key": str(d / f"{name}.key"),
            "connect_certificate": str(d / f"{name}.pem"),
        }
    path = d / f"client-{name}.json5"
    path.write_text(json.dumps({"transport": {"link": {"tls": tls}}}))
    return str(path)


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
def test_tls_acl_example_lets_only_the_operator_command(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from controller.cli import main

    _make_pki(tmp_path)
    port = free_tcp_port()
    endpoint = f"tls/localhost:{port}"
    # the documented file, with this test's certificate paths and port
    doc = Path(__file__).resolve().parents[2] / "docs" / "zenoh-tls-acl.json5"
    text = doc.read_text().replace("/etc/cablebot/tls", str(tmp_path))
    text = text.replace("tls/0.0.0.0:7447", endpoint)
    daemon_file = tmp_path / "daemon.json5"
    daemon_file.write_text(text)
    fake = FakeController().start()
    iface = zenoh_io.ZenohInterface(
        ZCfg(prefix="cablebot/tls", config_file=str(daemon_file)), fake, reply_timeout_s=1.0
    )
    iface.open()
    fake.publisher = iface
    common = ["--connect", endpoint, "--prefix", "cablebot/tls", "--timeout", "2"]
    try:
        # no client certificate: the TLS handshake fails, no session at all
        code = main(["status", *common, "--zenoh-config", _client_file(tmp_path, None)])
        assert code == exitcodes.NO_DAEMON
        assert "cannot connect" in capsys.readouterr().err
        # a valid certificate that is not the operator's: may watch, may not command
        viewer = ["--zenoh-config", _client_file(tmp_path, "viewer")]
        assert main(["status", *common, *viewer]) == 0
        assert main(["pose", "--count", "3", "--json", *common, *viewer]) == 0
        capsys.readouterr()
        assert main(["arm", *common, *viewer]) == exitcodes.NO_DAEMON
        assert "no cablebot daemon answered" in capsys.readouterr().err
        assert fake.submitted == []
        assert fake.state == "DISARMED"
        # the operator commands
        operator = ["--zenoh-config", _client_file(tmp_path, "operator")]
        assert main(["arm", *common, *operator]) == 0
        assert fake.state == "HOLDING"
    finally:
        fake.stop()
        iface.close()
