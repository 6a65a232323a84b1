"""The bus load a configuration implies (`drivers.busload`), its refusal in the configuration
and its place in `cablebot check-config` (text and `--json`)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from controller.cli import exitcodes, main
from controller.service.config import ConfigError, paper_robot_data, parse_config
from drivers import busload
from drivers.cia402 import busload as bits

REPO = Path(__file__).resolve().parents[2]


def test_typical_bits_sit_halfway_between_no_stuffing_and_the_worst_case() -> None:
    assert busload.typical_bits(8) == 47 + 64 + 12 == (47 + 64 + bits.worst_case_bits(8)) / 2
    assert busload.typical_bits(0) == 51
    with pytest.raises(ValueError):
        busload.typical_bits(9)


def test_four_cia402_drives_at_1_khz_need_132_percent_of_1_mbit() -> None:
    """SYNC + 4 x (RPDO1 6 bytes + RPDO2 4 bytes + TPDO1 8 bytes): 13 frames, 1311 typical bits
    (1317 measured on the simulated drives), 1435 worst."""
    load = busload.estimate(
        "cia402", 4, {}, rate_hz=1000.0, interface="socketcan", bitrate=1_000_000
    )
    assert load.frames_per_tick == 13
    assert load.bits_per_tick == 1311
    assert load.worst_bits_per_tick == 1435
    assert round(load.percent) == 131 and round(load.worst_percent) == 144
    refusal = load.refusal()
    assert refusal is not None
    assert "1000 Hz needs 131 % of the 1000000 bit/s bus, 144 % in the worst case" in refusal
    assert "at most 696 Hz fits" in refusal  # 1e6 / 1435 worst-case bits per tick
    half = busload.estimate(
        "cia402", 4, {}, rate_hz=500.0, interface="socketcan", bitrate=1_000_000
    )
    assert round(half.percent) == 66 and half.refusal() is None


def test_cia402_options_change_the_frames() -> None:
    lean = busload.tick_frames(
        "cia402", 4, {"velocity_offset": False, "torque": False}, rate_hz=1e3
    )
    assert [(f.name, f.n_bytes, f.count) for f in lean] == [
        ("SYNC", 0, 1.0),
        ("RPDO1", 6, 4.0),
        ("TPDO1", 6, 4.0),
    ]


def test_odrive_tick_frames() -> None:
    """4 Set_Input_Pos out and 4 encoder estimates back: 8 frames; RTR polls and torque
    telemetry add theirs (torque RTR every 10 ms at 500 Hz: a fifth of a round per tick)."""
    plain = busload.estimate("odrive", 4, {}, rate_hz=500.0, interface="socketcan", bitrate=None)
    assert plain.frames_per_tick == 8 and plain.bits_per_tick == 8 * 123
    assert plain.bitrate_assumed and plain.refusal() is None
    polled = busload.estimate(
        "odrive", 4, {}, rate_hz=1000.0, interface="socketcan", bitrate=None, encoder_rtr=True
    )
    assert polled.frames_per_tick == 12 and polled.refusal() is not None
    torque = busload.tick_frames(
        "odrive", 4, {}, rate_hz=500.0, torque_telemetry="rtr", torque_rtr_period_s=0.01
    )
    assert sum(f.count for f in torque) == pytest.approx(8 + 2 * 4 * 0.2)
    with pytest.raises(ValueError, match="no bus-load rule"):
        busload.tick_frames("stepper", 4, {}, rate_hz=1e3)


def test_a_tick_that_fits_only_without_its_worst_case_stuff_bits_is_refused() -> None:
    """Four ODrives at 1 kHz: 98 % of 1 Mbit/s typically, 108 % with every stuff bit. A tick
    that may not fit in its period is over the bus's capacity, not a remark."""
    load = busload.estimate(
        "odrive", 4, {}, rate_hz=1000.0, interface="socketcan", bitrate=1_000_000
    )
    assert round(load.percent) == 98 and round(load.worst_percent) == 108
    refusal = load.refusal()
    assert refusal is not None
    assert "1000 Hz needs 98 % of the 1000000 bit/s bus, 108 % in the worst case" in refusal
    assert "at most 925 Hz fits" in refusal  # 1e6 / 1080
    assert (
        busload.estimate(
            "odrive", 4, {}, rate_hz=925.0, interface="socketcan", bitrate=1_000_000
        ).refusal()
        is None
    )


@pytest.mark.parametrize("name", sorted(p.name for p in (REPO / "config").glob("*.toml")))
def test_every_shipped_robot_file_is_valid(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check-config", str(REPO / "config" / name)]) == exitcodes.OK, (
        capsys.readouterr().err
    )


def test_desk_file_states_its_bus_load_truly(capsys: pytest.CaptureFixture[str]) -> None:
    """The desk file's own comment gives its bus load: check-config must say the same."""
    path = REPO / "config" / "desk.toml"
    text = path.read_text()
    assert "49 % of 1 Mbit/s, 54 % in the worst case" in text
    assert main(["check-config", str(path)]) == exitcodes.OK
    out = capsys.readouterr().out
    assert "at 500 Hz: 49 % of 1000000 bit/s (worst 54 %)" in out
    assert "note:" not in out


def test_simulated_bus_is_stated_not_refused() -> None:
    load = busload.estimate(
        "cia402", 4, {}, rate_hz=1000.0, interface="udp_multicast", bitrate=None
    )
    assert load.percent > 100 and load.refusal() is None
    assert load.as_dict()["enforced"] is False


def _cia402_on_can0(rate_hz: float) -> dict[str, object]:
    data = paper_robot_data("t")
    data["drive"] = {"kind": "cia402", "counts_per_rev": 131072}
    for i, reel in enumerate(data["reels"]):
        reel["node_id"] = i + 1
    data["bus"] = {"interface": "socketcan", "channel": "can0", "bitrate": 1_000_000}
    data["sim"] = {"enabled": False}
    data["loop"] = {**data.get("loop", {}), "rate_hz": rate_hz}
    return data


def test_configuration_refuses_a_rate_the_bus_cannot_carry() -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(_cia402_on_can0(1000.0), "robot.toml")
    assert "loop.rate_hz" in str(info.value)
    assert "131 % of the 1000000 bit/s bus" in str(info.value)
    assert parse_config(_cia402_on_can0(500.0), "robot.toml").loop.rate_hz == 500.0


def test_check_config_states_the_bus_load(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    path = str(REPO / "config" / "cia402-desk.toml")
    assert main(["check-config", path]) == exitcodes.OK
    out = capsys.readouterr().out
    assert (
        "bus load   13 frames and 1311 bits per tick (worst 1435 with stuffing) at 500 Hz: "
        "66 % of 1000000 bit/s (worst 72 %)"
    ) in out
    assert main(["check-config", path, "--json"]) == exitcodes.OK
    data = json.loads(capsys.readouterr().out)
    assert data["bus_load"]["percent"] == 65.5
    assert data["bus_load"]["frames_per_tick"] == 13
    text = (REPO / "config" / "cia402-desk.toml").read_text()
    fast = tmp_path / "fast.toml"
    fast.write_text(text.replace("rate_hz = 500.0", "rate_hz = 1000.0", 1))
    assert main(["check-config", str(fast)]) == exitcodes.REFUSED
    err = capsys.readouterr().err
    assert "1000 Hz needs 131 %" in err
