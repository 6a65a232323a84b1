"""What the client verbs print and how they end: pose rate and sequence gaps, `--connect`
forms, progress while waiting, readable replies and status, a reader that goes away.

Against the in-process Zenoh interface with the fake controller (tests/fakes_zenoh.py), or a
bare Zenoh session publishing hand-made pose samples.
"""

from __future__ import annotations

import io
import itertools
import json
import os
import pty
import re
import select
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from controller.cli import client, exitcodes, main
from controller.service import zenoh_io
from controller.service.zenoh_io import free_tcp_port
from tests.cli.test_client import REPO, Daemon, run
from tests.fakes_zenoh import FakeController, ZCfg

CLI = [sys.executable, "-m", "controller.cli"]


@pytest.fixture
def daemon() -> Iterator[Daemon]:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    fake = FakeController(rate_hz=100.0)
    iface = zenoh_io.ZenohInterface(ZCfg(listen=(endpoint,)), fake, reply_timeout_s=1.0)
    iface.open()
    fake.publisher = iface
    fake.start()
    try:
        yield Daemon(fake, iface, endpoint)
    finally:
        fake.stop()
        iface.close()


# ------------------------------------------------------------------------------ --connect


@pytest.mark.parametrize(
    ("given", "endpoint"),
    [
        ("localhost:7447", "tcp/localhost:7447"),
        ("127.0.0.1:7448", "tcp/127.0.0.1:7448"),
        ("[::1]:7447", "tcp/[::1]:7447"),
        ("robot.local:7447", "tcp/robot.local:7447"),
        ("tcp/127.0.0.1:7447", "tcp/127.0.0.1:7447"),
        ("tls/robot.local:7447", "tls/robot.local:7447"),
        ("udp/10.0.0.2:7447#iface=eth0", "udp/10.0.0.2:7447#iface=eth0"),
        ("unixsock-stream//tmp/zenoh.sock", "unixsock-stream//tmp/zenoh.sock"),
    ],
)
def test_connect_accepts_host_port_and_endpoints(given: str, endpoint: str) -> None:
    assert client.normalize_endpoint(given) == endpoint


@pytest.mark.parametrize(
    "given", ["localhost", "foo", "localhost:0", "localhost:99999", "tcp/localhost", "http/x:1", ""]
)
def test_connect_rejects_other_forms_in_one_line(
    given: str, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "status", "--connect", given)
    assert code == exitcodes.USAGE
    assert out == ""
    assert err == f"cablebot: --connect: expected tcp/HOST:PORT or HOST:PORT, got {given!r}\n"


def test_connect_host_port_reaches_the_daemon(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    host_port = daemon.endpoint.removeprefix("tcp/")
    code, out, err = run(capsys, "status", "--connect", host_port, "--prefix", "cablebot/test")
    assert code == exitcodes.OK, err
    assert out.startswith("state      DISARMED")


def test_zenoh_errors_are_one_line_without_source_paths() -> None:
    text = (
        'Json5Err(Message { msg: "Endpoints must be of the form <protocol>/<address>: x at '
        '/root/.cargo/git/checkouts/zenoh/commons/zenoh-protocol/src/core/endpoint.rs:615.",\n'
        " location: None }) at /root/.cargo/git/zenoh/src/api/config.rs:86."
    )
    cleaned = client.clean_zenoh_error(text)
    assert "\n" not in cleaned and ".rs" not in cleaned and "/root" not in cleaned
    assert "Endpoints must be of the form" in cleaned


# ------------------------------------------------------------------------------ pose


def test_seq_gaps_counts_missed_samples_and_restarts() -> None:
    g = client.SeqGaps()
    assert [g.update(s) for s in (5, 6, 9, 10, 14)] == [0, 0, 2, 0, 3]
    assert (g.received, g.missed, g.restarts) == (5, 5, 0)
    assert g.update(1) == 0  # the daemon restarted: not a gap
    assert g.update(2) == 0
    assert (g.missed, g.restarts) == (5, 1)


def test_pose_is_rate_limited_by_default(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    # The fake publishes 100 samples a second; the default prints 5 lines a second.
    code, out, _ = run(capsys, "pose", "--count", "4", *daemon.args())
    assert code == 0
    seqs = [int(line.split()[1]) for line in out.splitlines() if line.startswith("seq ")]
    assert len(seqs) == 4
    steps = [b - a for a, b in itertools.pairwise(seqs)]
    assert min(steps) >= 10, steps  # ~20 samples (0.2 s at 100/s) between printed lines
    code, out, _ = run(capsys, "pose", "--count", "3", "--rate", "2", *daemon.args())
    seqs = [int(line.split()[1]) for line in out.splitlines() if line.startswith("seq ")]
    assert min(b - a for a, b in itertools.pairwise(seqs)) >= 25, seqs


def test_pose_json_prints_every_sample_and_reports_each_gap(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "pose", "--count", "30", "--json", *daemon.args())
    assert code == 0
    seqs = [json.loads(line)["seq"] for line in out.splitlines()]
    assert len(seqs) == 30
    gaps = [b - a - 1 for a, b in itertools.pairwise(seqs) if b - a > 1]
    # Every sample is printed: any jump in seq is a sample lost on the way, and reported.
    assert re.findall(r"gap: (\d+) samples missed", err) == [str(g) for g in gaps]


def _publish_with_gaps(endpoint: str, stop: threading.Event) -> None:
    """Publish pose samples whose seq skips 3 after every 5th sample, until `stop`."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    with zenoh.open(conf) as session:
        pub = session.declare_publisher("cablebot/test/pose")
        seq = 0
        while not stop.is_set():
            seq += 4 if seq % 5 == 0 else 1  # 4, 5, 9, 10, 14, 15, ...: 3 missing each time
            sample = {
                "seq": seq,
                "stamp_ns": time.time_ns(),
                "position_m": [0.0, 0.0, 2.0],
                "cable_lengths_m": [1.0, 1.0, 1.0, 1.0],
                "residual_m": 0.0,
                "valid": True,
                "state": "HOLDING",
            }
            pub.put(json.dumps(sample).encode())
            stop.wait(0.01)


@pytest.mark.parametrize("json_mode", [False, True])
def test_pose_reports_gaps_in_seq(json_mode: bool, capsys: pytest.CaptureFixture[str]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    stop = threading.Event()
    pub = threading.Thread(target=_publish_with_gaps, args=(endpoint, stop), daemon=True)
    pub.start()
    try:
        argv = ["pose", "--count", "12", "--rate", "0", "--connect", endpoint]
        argv += ["--prefix", "cablebot/test", "--timeout", "10"]
        if json_mode:
            argv.append("--json")
        code = None
        for _ in range(20):  # the publisher's session may still be opening
            code, out, err = run(capsys, *argv)
            if code == exitcodes.OK:
                break
        assert code == exitcodes.OK, err
    finally:
        stop.set()
        pub.join(5.0)
    gap_stream = err if json_mode else out
    assert gap_stream.count("gap: 3 samples missed") >= 2, (out, err)
    assert re.search(r"pose: \d+ samples received, \d+ missed", err)
    if not json_mode:
        # the gap line comes before the pose line that follows the gap
        lines = out.splitlines()
        i = lines.index("gap: 3 samples missed", 1)
        assert int(lines[i - 1].split()[1]) % 5 == 0, lines
        assert int(lines[i + 1].split()[1]) % 5 == 4, lines


def test_pose_rate_must_not_be_negative(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "pose", "--rate", "-1")
    assert code == exitcodes.USAGE
    assert "--rate must be a number >= 0" in err


# ------------------------------------------------------------------------------ --wait


def test_path_remaining_follows_the_legs_in_order() -> None:
    legs = [([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]), ([1.0, 0.0, 0.0], [1.0, 1.0, 0.0])]
    assert client.path_remaining_m(legs, [0.25, 0.0, 0.0], 0) == (0, pytest.approx(1.75))
    assert client.path_remaining_m(legs, [1.0, 0.5, 0.0], 0) == (1, pytest.approx(0.5))
    # A path back over itself: the leg index only moves forward.
    back = [*legs, ([1.0, 1.0, 0.0], [1.0, 0.0, 0.0])]
    k, rest = client.path_remaining_m(back, [1.0, 0.6, 0.0], 1)
    assert k == 1 and rest == pytest.approx(0.4 + 1.0)
    k, rest = client.path_remaining_m(back, [1.0, 0.4, 0.0], 2)
    assert k == 2 and rest == pytest.approx(0.4)


def _run_on_pty(argv: list[str], timeout_s: float = 60.0) -> tuple[int, str]:
    """Run the CLI with stdout on a pseudo-terminal; returns (exit code, all output)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [*CLI, *argv], cwd=REPO, stdout=slave, stderr=subprocess.PIPE, close_fds=True
    )
    os.close(slave)
    chunks: list[bytes] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            try:
                data = os.read(master, 4096)
            except OSError:  # the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        elif proc.poll() is not None:
            break
    os.close(master)
    code = proc.wait(timeout=10)
    assert proc.stderr is not None
    proc.stderr.close()
    return code, b"".join(chunks).decode(errors="replace")


def test_move_wait_shows_progress_in_place_on_a_terminal_only(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run(capsys, "arm", *daemon.args())[0] == 0
    code, text = _run_on_pty(["move", "0.6", "0", "2", "--speed", "0.5", "--wait", *daemon.args()])
    assert code == 0, text
    updates = re.findall(r"\r\x1b\[Kmove: ([0-9.]+) m to go", text)
    assert len(updates) >= 3, repr(text)
    remaining = [float(v) for v in updates]
    assert remaining[0] > remaining[-1]
    assert text.rstrip().splitlines()[-1].lstrip("\r\x1b[K").startswith("arrived: ")
    # not a terminal: the reply and the arrival, nothing else
    code, out, _ = run(capsys, "move", "0", "0", "2", "--speed", "0.5", "--wait", *daemon.args())
    assert code == 0
    assert "\r" not in out and "to go" not in out
    lines = out.splitlines()
    assert len(lines) == 2 and lines[1].startswith("arrived: ")


# ------------------------------------------------------------------------------ replies


def test_stop_says_what_the_robot_does() -> None:
    assert client.format_reply("stop", {"ok": True, "state": "MOVING"}) == (
        "stop: braking to a hold"
    )
    assert client.format_reply("stop", {"ok": True, "state": "HOLDING"}) == (
        "stop: holding (nothing was moving)"
    )
    assert client.format_reply("stop", {"ok": True, "state": "DISARMED"}) == (
        "stop: nothing to stop (state DISARMED)"
    )


def test_home_prints_a_readable_line() -> None:
    reply = {
        "ok": True,
        "position_m": [0.0, 0.5, 2.0],
        "offsets_rev": {"0": -12.345678901234567, "1": 3.141592653589793},
        "saved": True,
        "state_file": "/var/lib/cablebot/desk-offsets.json",
    }
    assert client.format_reply("home", reply) == (
        "home: at x=+0.0000 y=+0.5000 z=+2.0000 m; offsets (turns) node 0 -12.3457,"
        " node 1 +3.1416; saved to /var/lib/cablebot/desk-offsets.json"
    )
    reply.update(saved=False, error="No space left on device")
    assert client.format_reply("home", reply).endswith("; NOT SAVED: No space left on device")
    del reply["error"]
    assert client.format_reply("home", reply).endswith("not saved (no [homing] state_file)")


def test_pretension_prints_its_start_its_progress_and_its_end() -> None:
    start = {
        "ok": True,
        "state": "PRETENSIONING",
        "tensions_n": [104.44, 99.5],
        "speed_limited": True,
    }
    assert client.format_reply("pretension", start) == (
        "pretension: the reels pull in torque control with 104.4, 99.5 N; waiting until they"
        " are still"
    )
    start["speed_limited"] = False
    assert "(the drives' own velocity limit caps their speed)" in client.format_reply(
        "pretension", start
    )
    result = {
        "ok": True,
        "position_m": [0.0, 0.0, 2.0],
        "still_after_s": 3.104,
        "offsets_rev": {"0": -0.43381, "1": 1.5},
        "saved": False,
        "measured_tensions_n": [104.41, 104.47],
    }
    assert client.format_pretension_result(result) == (
        "pretension: still after 3.10 s; homed at x=+0.0000 y=+0.0000 z=+2.0000 m; offsets"
        " (turns) node 0 -0.4338, node 1 +1.5000; not saved (no [homing] state_file);"
        " measured tensions 104.4, 104.5 N"
    )
    running = {
        "state": "PRETENSIONING",
        "pretension": {
            "active": True,
            "position_m": [0.0, 0.0, 2.0],
            "elapsed_s": 1.25,
            "fastest_cable_mps": 0.0123,
            "result": None,
        },
    }
    assert "pretension running 1.2 s, fastest cable 12.3 mm/s, home at x=+0.000 y=+0.000" in (
        client.format_status(running)
    )
    ended = {
        "state": "FAULT",
        "pretension": {"active": False, "result": {"ok": False, "reason": "x"}},
    }
    assert "pretension ended without homing: x" in client.format_status(ended)


def test_move_reply_names_target_speed_and_a_limited_speed() -> None:
    reply = {"ok": True, "target_m": [0.5, 0.0, 2.0], "speed_mps": 2.0}
    assert (
        client.format_reply("move", reply) == "move: to x=+0.500 y=+0.000 z=+2.000 m at 2.000 m/s"
    )
    reply["speed_limited_to_mps"] = 2.0
    assert client.format_reply("move", reply).endswith(
        "(speed limited to the robot's maximum, 2.000 m/s)"
    )
    assert client.format_reply("path", {"ok": True, "points": 4, "speed_mps": 0.3}) == (
        "path: 4 points at 0.300 m/s"
    )
    queued = {"queued_points": 1500, "queued_s": 2.04, "queue_full": False}
    reply = {"ok": True, "points": 1000, "append": True, "speed_mps": 0.1, **queued}
    assert client.format_reply("path", reply) == (
        "path: 1000 appended at 0.100 m/s; 1500 queued (2.0 s)"
    )
    reply["queue_full"] = True
    assert client.format_reply("path", reply).endswith("1500 queued (2.0 s, full)")


def test_refusal_prints_the_daemons_reason_verbatim(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run(capsys, "arm", *daemon.args())[0] == 0
    assert run(capsys, "estop", *daemon.args())[0] == 0
    code, out, err = run(capsys, "arm", *daemon.args())
    assert code == exitcodes.REFUSED
    assert out == ""
    assert err == "cablebot: refused: not allowed in ESTOPPED (needs DISARMED)\n"


def test_status_names_axis_states_faults_and_tensions() -> None:
    st: dict[str, Any] = {
        "state": "FAULT",
        "reason": "axis_error: node 1",
        "pose": {"position_m": None},
        "setpoint_m": [0.0, 0.0, 2.0],
        "axes": [
            {
                "node_id": 0,
                "ready": True,
                "state": "CLOSED_LOOP_CONTROL",
                "fault": None,
                "axis_state": 8,
                "axis_error": 0,
                "age_s": 0.002,
            },
            {
                "node_id": 1,
                "ready": False,
                "state": "IDLE",
                "fault": "DRV_FAULT|ESTOP_REQUESTED (0x2000020)",
                "axis_state": 1,
                "axis_error": 0x2000000 | 0x20,
                "age_s": 0.003,
            },
            {
                "node_id": 2,
                "ready": False,
                "state": "state 99",
                "fault": "0x80000000 (0x80000000)",
                "axis_state": 99,
                "axis_error": 0x80000000,
                "age_s": None,
            },
            {
                "node_id": 4,
                "ready": False,
                "state": "Fault",
                "fault": "EMCY 0x2310 Continuous over-current (Current)",
                "axis_state": 1,
                "axis_error": 0x2310,
                "age_s": 0.004,
            },
            # A status without the names (an older daemon): the raw numbers.
            {"node_id": 5, "axis_state": 1, "axis_error": 0x20, "age_s": 0.005},
        ],
        "tensions_n": [120.25, 80.0, None],
    }
    lines = client.format_status(st).splitlines()
    assert lines[0] == "state      FAULT (axis_error: node 1)"
    assert "set-point  x=+0.0000 y=+0.0000 z=+2.0000 m" in lines
    axes = [line for line in lines if line.startswith("axis ")]
    assert (
        axes[0] == "axis 0     CLOSED_LOOP_CONTROL, error none, reading 2.0 ms ago  tension 120.2 N"
    )
    assert axes[1] == (
        "axis 1     IDLE, error DRV_FAULT|ESTOP_REQUESTED (0x2000020), reading 3.0 ms ago"
        "  tension 80.0 N"
    )
    assert axes[2] == "axis 2     state 99, error 0x80000000 (0x80000000), reading never"
    assert axes[3] == (
        "axis 4     Fault, error EMCY 0x2310 Continuous over-current (Current), reading 4.0 ms ago"
    )
    assert axes[4] == "axis 5     state 1, error 0x20, reading 5.0 ms ago"


# ------------------------------------------------------------------------------ pipes


class _ClosedPipe(io.StringIO):
    def write(self, s: str) -> int:
        raise BrokenPipeError(32, "Broken pipe")


def test_a_closed_pipe_ends_any_verb_quietly(
    daemon: Daemon, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    for argv in (["status", "--json"], ["status"], ["pose", "--json"], ["pose"], ["estop"]):
        with monkeypatch.context() as m:
            m.setattr(sys, "stdout", _ClosedPipe())
            code = main([*argv, *daemon.args()])
        assert code == exitcodes.BROKEN_PIPE, argv
        assert capsys.readouterr().err == "", argv


def test_pose_into_a_closed_pipe_exits_quietly(daemon: Daemon) -> None:
    proc = subprocess.Popen(
        [*CLI, "pose", "--json", *daemon.args()],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    first = proc.stdout.readline()
    assert json.loads(first)["state"] == "DISARMED"
    proc.stdout.close()  # like `| head -1`
    code = proc.wait(timeout=30)
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert code == exitcodes.BROKEN_PIPE
    assert err == ""


def _fault_after_acceptance(
    monkeypatch: pytest.MonkeyPatch, cmd_key: str, accepted: dict[str, Any], reason: str
) -> None:
    """The daemon accepts `cmd_key` (replying `accepted`), and its status then says FAULT."""
    real = client.query

    def query(session: Any, key: str, payload: Any, timeout_s: float) -> Any:
        if key.endswith(cmd_key):
            return accepted
        if key.endswith("/status"):
            return {"state": "FAULT", "reason": reason, "pretension": {"active": False}}
        return real(session, key, payload, timeout_s)

    monkeypatch.setattr(client, "query", query)


def test_a_pretension_accepted_then_faulted_says_so_not_refused(
    daemon: Daemon, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    reason = "stale_encoder: node 0 age 0.688 s > 0.5 s"
    start = {"ok": True, "state": "PRETENSIONING", "tensions_n": [104.4], "speed_limited": True}
    _fault_after_acceptance(monkeypatch, "cmd/pretension", start, reason)
    code, out, err = run(capsys, "home", "0", "0", "2", "--pretension", *daemon.args())
    assert code == exitcodes.REFUSED
    assert out.startswith("pretension: the reels pull in torque control")
    assert err == f"cablebot: accepted, then the pre-tension ended in FAULT: {reason}\n"


def test_an_arm_accepted_then_faulted_says_so_not_refused(
    daemon: Daemon, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    reason = "arming_timeout: node 2 not in closed loop after 2 s"
    _fault_after_acceptance(monkeypatch, "cmd/arm", {"ok": True, "state": "ARMING"}, reason)
    code, out, err = run(capsys, "arm", *daemon.args())
    assert code == exitcodes.REFUSED
    assert out == "arm: ok, state ARMING\n"
    assert err == f"cablebot: accepted, then the arming ended in FAULT: {reason}\n"


def test_an_arm_that_arms_exits_0_without_an_error_line(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "arm", *daemon.args())
    assert (code, err) == (0, "")
    assert out.startswith("arm:")
