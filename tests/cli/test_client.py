"""The client CLI verbs against an in-process Zenoh interface with a fake controller."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from controller.cli import client, exitcodes, main
from controller.service import zenoh_io
from controller.service.zenoh_io import free_tcp_port
from tests.fakes_zenoh import FakeController, ZCfg

REPO = Path(__file__).resolve().parents[2]


class Daemon:
    def __init__(self, fake: FakeController, iface: zenoh_io.ZenohInterface, endpoint: str):
        self.fake = fake
        self.iface = iface
        self.endpoint = endpoint

    def args(self) -> list[str]:
        return ["--connect", self.endpoint, "--prefix", "cablebot/test"]


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


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


# ------------------------------------------------------------------------------ no daemon


def test_no_daemon_exits_3_with_a_clear_message(capsys: pytest.CaptureFixture[str]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    t0 = time.monotonic()
    for verb in (["status"], ["arm"], ["move", "0", "0", "1"], ["pose", "--count", "1"]):
        code, out, err = run(capsys, *verb, "--connect", endpoint)
        assert code == exitcodes.NO_DAEMON, verb
        assert out == ""
        assert f"no cablebot daemon answered on cablebot/default via {endpoint}" in err
    assert time.monotonic() - t0 < 10.0  # fails fast: nothing listens


def test_wrong_prefix_exits_3(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "status", "--connect", daemon.endpoint, "--prefix", "cablebot/x")
    assert code == exitcodes.NO_DAEMON
    assert "no cablebot daemon answered on cablebot/x" in err


def test_pose_times_out_when_nothing_is_published(capsys: pytest.CaptureFixture[str]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    fake = FakeController()  # not started: publishes nothing
    iface = zenoh_io.ZenohInterface(ZCfg(listen=(endpoint,)), fake)
    iface.open()
    try:
        code, _, err = run(
            capsys, "pose", "--connect", endpoint, "--prefix", "cablebot/test", "--timeout", "0.5"
        )
    finally:
        iface.close()
    assert code == exitcodes.NO_DAEMON
    assert "no pose sample within 0.5 s" in err


# ------------------------------------------------------------------------------ verbs


def test_status_human_and_json(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "status", *daemon.args())
    assert code == 0
    assert out.splitlines()[0] == "state      DISARMED"
    assert "position   x=+0.0000 y=+0.0000 z=+2.0000 m" in out
    code, out, _ = run(capsys, "status", "--json", *daemon.args())
    assert code == 0
    assert json.loads(out)["state"] == "DISARMED"


def test_pose_count_json_and_human(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "pose", "--count", "5", "--json", *daemon.args())
    assert code == 0
    samples = [json.loads(line) for line in out.splitlines()]
    assert len(samples) == 5
    seqs = [s["seq"] for s in samples]
    assert seqs == sorted(seqs)
    code, out, _ = run(capsys, "pose", "--count", "2", *daemon.args())
    assert code == 0
    # A busy machine may drop a sample between the two: `pose` then says so in a line of its
    # own ("gap: N samples missed"), as documented; the two pose lines must still be there.
    lines = [line for line in out.splitlines() if not line.startswith("gap: ")]
    assert len(lines) == 2
    assert lines[0].startswith("seq ")
    assert "state DISARMED  x=+0.000 y=+0.000 z=+2.000 m  resid 0.0 mm" in lines[0]


def test_refusal_exits_1_with_the_reason(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    code, out, err = run(capsys, "move", "0.1", "0", "2", *daemon.args())
    assert code == 1
    assert out == ""
    assert "refused: not allowed in DISARMED (needs HOLDING/MOVING)" in err
    code, _, err = run(capsys, "reset", *daemon.args())
    assert code == 1
    assert "not allowed in DISARMED" in err


def test_arm_move_wait_stop_estop_reset(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(capsys, "arm", *daemon.args())[:2] == (0, "arm: ok, state HOLDING\n")
    code, out, err = run(
        capsys, "move", "0.2", "-0.1", "2.1", "--speed", "1.0", "--wait", *daemon.args()
    )
    assert code == 0, err
    assert out.splitlines()[-1].startswith("arrived: ")
    assert daemon.fake.position_m == (0.2, -0.1, 2.1)
    assert daemon.fake.speed_mps == 1.0
    code, _, _ = run(capsys, "stop", *daemon.args())
    assert code == 0
    code, out, _ = run(capsys, "estop", "--json", *daemon.args())
    assert code == 0
    assert json.loads(out) == {"ok": True, "state": "ESTOPPED"}
    assert run(capsys, "reset", *daemon.args())[0] == 0
    assert daemon.fake.state == "DISARMED"
    code, _, _ = run(capsys, "home", "0", "0", "1.5", *daemon.args())
    assert code == 0
    assert daemon.fake.position_m == (0.0, 0.0, 1.5)


def test_move_wait_reports_a_fault(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    run(capsys, "arm", *daemon.args())
    import threading

    def estop_soon() -> None:
        time.sleep(0.3)
        daemon.fake.submit(client_estop())

    th = threading.Thread(target=estop_soon)
    th.start()
    code, _, err = run(
        capsys, "move", "0.9", "0.9", "2.9", "--speed", "0.1", "--wait", *daemon.args()
    )
    th.join()
    assert code == 1
    assert "went ESTOPPED during the motion" in err


def client_estop() -> Any:
    from controller.core.commands import Estop

    return Estop()


def test_move_wait_timeout(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    run(capsys, "arm", *daemon.args())
    code, _, err = run(
        capsys,
        "move",
        "0.9",
        "0",
        "2",
        "--speed",
        "0.01",
        "--wait",
        "--wait-timeout",
        "0.5",
        *daemon.args(),
    )
    assert code == exitcodes.WAIT_TIMEOUT
    assert "not at the target after 0.5 s" in err


def test_bad_numbers_are_not_sent(daemon: Daemon, capsys: pytest.CaptureFixture[str]) -> None:
    for argv in (
        ["move", "nan", "0", "1"],
        ["home", "0", "inf", "1"],
        ["move", "0", "0", "1", "--speed", "-1"],
    ):
        code, _, err = run(capsys, *argv, *daemon.args())
        assert code == 1, argv
        assert "finite" in err or "> 0" in err
    assert daemon.fake.submitted == []


# ------------------------------------------------------------------------------ path files


def test_path_file_formats(tmp_path: Path) -> None:
    f = tmp_path / "p.json"
    f.write_text("[[0, 0, 1], [0.5, 0, 1]]")
    assert client.load_path_file(str(f)) == {"points_m": [[0, 0, 1], [0.5, 0, 1]]}
    f.write_text('{"points_m": [[0, 0, 1]], "speed_mps": 0.2}')
    assert client.load_path_file(str(f)) == {"points_m": [[0, 0, 1]], "speed_mps": 0.2}
    f = tmp_path / "p.csv"
    f.write_text("x,y,z\n# a comment\n0,0,1\n0.5, 0, 1.25\n\n1 0 1\n")
    assert client.load_path_file(str(f)) == {
        "points_m": [[0.0, 0.0, 1.0], [0.5, 0.0, 1.25], [1.0, 0.0, 1.0]]
    }


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("[[0, 0, NaN]]", "invalid JSON"),
        ("[[0, 0]]", "expected [x, y, z]"),
        ("[]", "no points in it (an empty list): nothing to fly"),
        ('{"points": [[0, 0, 1]]}', "unknown field(s): points"),
        ("0,0,1\n0,zero,1\n", "line 2"),
        ("0,0,1,4\n", "expected three finite numbers"),
    ],
)
def test_bad_path_files(tmp_path: Path, text: str, reason: str) -> None:
    f = tmp_path / "bad.txt"
    f.write_text(text)
    with pytest.raises(client.InputError, match=None) as info:
        client.load_path_file(str(f))
    assert reason in str(info.value)


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("", "empty"),
        ("x,y,z\n# no points yet\n\n", "only a header, comments or blank lines"),
        ("[]", "an empty list"),
        ('{"points_m": [], "speed_mps": 0.5}', "an empty list"),
    ],
)
def test_a_path_file_without_points_says_so(tmp_path: Path, text: str, what: str) -> None:
    # as an empty G-code file does ("no G-code in it (empty): nothing to run"), in the file's
    # terms rather than the command's field ("points_m: expected a non-empty list")
    f = tmp_path / "none.csv"
    f.write_text(text)
    with pytest.raises(client.InputError) as info:
        client.load_path_file(str(f), stream=True)
    assert str(info.value) == f"{f}: no points in it ({what}): nothing to fly"


def test_a_bad_point_deep_in_a_long_json_file_is_named_by_its_place_in_the_file(
    tmp_path: Path,
) -> None:
    # streamed in chunks of MAX_PATH_POINTS_SENT: the point's index within its chunk
    # ("(points 3000 on): points_m[998]") is no place in the file
    points: list[list[float]] = [[0.0, 0.0, 2.0 + i * 1e-4] for i in range(5000)]
    points[3998] = [1.0, 2.0]
    f = tmp_path / "long.json"
    f.write_text(json.dumps({"points_m": points}))
    with pytest.raises(client.InputError) as info:
        client.load_path_file(str(f), stream=True)
    assert str(info.value) == f"{f}: point 3999: expected [x, y, z], got [1.0, 2.0]"


def test_path_command_and_wait(
    daemon: Daemon, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "p.csv"
    f.write_text("0.1,0,2\n0.1,0.1,2\n0,0.1,2.05\n")
    run(capsys, "arm", *daemon.args())
    code, out, err = run(capsys, "path", str(f), "--speed", "1.0", "--wait", *daemon.args())
    assert code == 0, err
    assert "arrived" in out
    assert daemon.fake.position_m == (0.0, 0.1, 2.05)
    code, _, err = run(capsys, "path", str(tmp_path / "missing.csv"), *daemon.args())
    assert code == 1
    assert "cannot read" in err


# ------------------------------------------------------------------------------ formatting


def test_format_pose_without_a_valid_position() -> None:
    line = client.format_pose(
        {"seq": 7, "position_m": None, "residual_m": None, "state": "FAULT", "valid": False}
    )
    assert line == "seq 7  state FAULT  x=   ---  y=   ---  z=   ---  m (pose not valid)"


def test_cli_process_exit_code_without_daemon() -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "controller.cli",
            "estop",
            "--connect",
            f"tcp/127.0.0.1:{free_tcp_port()}",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == exitcodes.NO_DAEMON
    assert "no cablebot daemon answered" in proc.stderr


def test_move_wait_json_prints_the_arrival(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run(capsys, "arm", *daemon.args())[0] == 0
    code, out, err = run(
        capsys, "move", "0.2", "-0.1", "2.1", "--speed", "1.0", "--wait", "--json", *daemon.args()
    )
    assert code == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    assert lines[0]["state"] == "MOVING"
    assert lines[-1]["arrived"] is True
    assert lines[-1]["pose"]["state"] == "HOLDING"
    assert lines[-1]["pose"]["position_m"] == pytest.approx([0.2, -0.1, 2.1], abs=1e-3)


def test_arm_when_already_armed_succeeds_saying_so(
    daemon: Daemon, capsys: pytest.CaptureFixture[str]
) -> None:
    assert run(capsys, "arm", *daemon.args())[0] == 0
    assert run(capsys, "arm", *daemon.args()) == (0, "arm: already armed, state HOLDING\n", "")
    code, out, _ = run(capsys, "arm", "--json", *daemon.args())
    assert code == 0
    assert json.loads(out) == {"ok": True, "state": "HOLDING", "already_armed": True}
    assert run(capsys, "estop", *daemon.args())[0] == 0
    code, _, err = run(capsys, "arm", *daemon.args())
    assert code == exitcodes.REFUSED and "not allowed in ESTOPPED" in err
