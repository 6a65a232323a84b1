"""controller.cli.daemon_robot: the robot a daemon serves as its clients read it, and a robot
file compared with it (which robot each is, every setting that differs)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from controller.cli.daemon_robot import (
    MAX_DIFFERENCES,
    DaemonRobot,
    RobotMismatch,
    check_agrees,
    robot_differences,
    robot_from_text,
)
from controller.service.config import (
    ConfigError,
    default_config,
    load_config,
    paper_robot_data,
    parse_config,
    robot_description,
    robot_digest,
)
from controller.service.config.tomltext import to_toml

CONFIGS = sorted((Path(__file__).resolve().parents[2] / "config").glob("*.toml"))


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_the_toml_writer_gives_back_every_shipped_robot(path: Path) -> None:
    data = tomllib.loads(path.read_text())
    assert tomllib.loads(to_toml(data)) == data


def test_the_built_in_robot_is_described_by_a_toml_text_of_the_same_robot() -> None:
    cfg = default_config()
    desc = robot_description(cfg)
    assert desc["name"] == "default" and desc["source"] == "<built-in default>"
    assert desc["digest"] == robot_digest(cfg.text) and desc["digest"].startswith("sha256:")
    assert tomllib.loads(desc["toml"]) == paper_robot_data("default")
    assert robot_differences(robot_from_text(desc["toml"], "served"), cfg) == []


def test_a_loaded_robot_keeps_its_file_text_comments_and_all() -> None:
    path = CONFIGS[0]
    assert load_config(path).text == path.read_text()


def _desk(tmp_path: Path, **tables: dict[str, object]) -> Path:
    data = tomllib.loads((CONFIGS[0].parent / "desk.toml").read_text())
    data.update(tables)
    out = tmp_path / f"desk-{len(list(tmp_path.iterdir()))}.toml"
    out.write_text(to_toml(data))
    return out


def test_robot_differences_name_every_setting_that_differs(tmp_path: Path) -> None:
    desk = load_config(_desk(tmp_path))
    data = tomllib.loads(desk.text)
    data["gcode"] = {"origin_m": [-0.1075, -0.1075, 0.1]}
    data["reels"][1]["anchor_m"] = [-0.5, 0.5, 0.81]
    data["limits"]["max_speed_mps"] = 0.5
    other = parse_config(data, "other.toml")
    diffs = {key: (a, b) for key, a, b in robot_differences(desk, other)}
    assert diffs == {
        "reels[1].anchor_m": ((-0.5, 0.5, 0.8), (-0.5, 0.5, 0.81)),
        "limits.max_speed_mps": (desk.limits.max_speed_mps, 0.5),
        "gcode.origin_m": ((0.0, 0.0, 0.0), (-0.1075, -0.1075, 0.1)),
    }
    assert robot_differences(desk, parse_config(tomllib.loads(desk.text), "copy.toml")) == []


def _served(cfg_path: Path, prefix: str = "cablebot/desk") -> DaemonRobot:
    text = cfg_path.read_text()
    cfg = robot_from_text(text, str(cfg_path))
    return DaemonRobot(prefix, cfg.name, str(cfg_path), robot_digest(text), text, cfg)


def test_a_file_of_another_robot_is_refused_naming_both_and_what_differs(
    tmp_path: Path,
) -> None:
    daemon = _served(_desk(tmp_path, gcode={"origin_m": [-0.1075, -0.1075, 0.1]}))
    mine = _desk(tmp_path)
    with pytest.raises(RobotMismatch) as info:
        check_agrees(daemon, robot_from_text(mine.read_text(), str(mine)), str(mine))
    assert str(info.value) == (
        f"--config {mine} (robot 'desk') is not the robot the daemon on cablebot/desk runs"
        f" ('desk', from {daemon.source}): they differ in gcode.origin_m ([0, 0, 0] in --config,"
        " [-0.1075, -0.1075, 0.1] at the daemon). The daemon's robot is the one that moves:"
        " leave out --config, or give its file"
    )
    same = _desk(tmp_path, gcode={"origin_m": [-0.1075, -0.1075, 0.1]})
    check_agrees(daemon, robot_from_text(same.read_text(), str(same)), str(same))  # agrees


def test_a_refusal_lists_the_settings_of_motion_first_and_counts_the_rest(
    tmp_path: Path,
) -> None:
    paper = default_config()
    daemon = _served(_desk(tmp_path))
    with pytest.raises(RobotMismatch) as info:
        check_agrees(daemon, paper, "paper.toml")
    text = str(info.value)
    assert text.index("they differ in name ('default' in --config, 'desk' at the daemon)") > 0
    assert text.index("reels[0].") < text.index(" more settings") and "bus." not in text
    # named by the file's keys: a reel's model is not a table of the file
    assert "reels[0].metres_per_rev (0.5 in --config, 0.0942478 at the daemon)" in text, text
    assert ".reel." not in text


def test_one_setting_beyond_the_list_is_one_more_setting(tmp_path: Path) -> None:
    mine = _desk(tmp_path)
    data = tomllib.loads(mine.read_text())
    for i, reel in enumerate(data["reels"]):  # 4 anchors and 3 more: one beyond the list
        reel["anchor_m"] = [reel["anchor_m"][0], reel["anchor_m"][1], 0.81]
        if i < 3:
            reel["gear_ratio"] = 2.0
    assert len(data["reels"]) + 3 == MAX_DIFFERENCES + 1
    other = tmp_path / "other.toml"
    other.write_text(to_toml(data))
    with pytest.raises(RobotMismatch) as info:
        check_agrees(_served(mine), robot_from_text(other.read_text(), str(other)), str(other))
    assert str(info.value).endswith(
        " and 1 more setting. The daemon's robot is the one that moves: leave out --config, or"
        " give its file"
    )
    assert "reels[0].gear_ratio (2 in --config, 1 at the daemon)" in str(info.value)


def test_files_of_the_daemons_machine_are_neither_read_nor_compared(tmp_path: Path) -> None:
    data = tomllib.loads((CONFIGS[0].parent / "cia402-sim.toml").read_text())
    data["drive"]["eds"] = "/nonexistent/drive.eds"
    data["zenoh"] = {**data.get("zenoh", {}), "config_file": "/nonexistent/zenoh.json5"}
    text = to_toml(data)
    with pytest.raises(ConfigError, match=r"drive\.eds"):
        parse_config(tomllib.loads(text), "here")  # the daemon's machine has them, not this one
    served = robot_from_text(text, "served")
    plain = load_config(CONFIGS[0].parent / "cia402-sim.toml")
    assert robot_differences(served, plain) == []
