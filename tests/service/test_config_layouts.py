"""Robot files of any layout of 3 to 8 cables: the shipped Hangprinters, and the layouts refused.

A file whose floor is at or above its lowest anchor (minus `top_margin_m`) and whose anchors
do not lie in one plane works among its anchors (`Geometry.hanging` False); `check-config`
prints the workspace's volume and the part of it where the payload is held, and refuses a
layout that cannot hold the payload anywhere, with the reason.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from controller.cli import exitcodes, main
from controller.core.workspace import Workspace
from controller.service.config import ConfigError, load_config

REPO = Path(__file__).resolve().parents[2]
HP4 = REPO / "config" / "hangprinter-v4.toml"
HP5 = REPO / "config" / "hangprinter-5.toml"


@pytest.mark.parametrize("path", [HP4, HP5], ids=["v4", "five"])
def test_the_hangprinter_files_work_among_their_anchors(path: Path) -> None:
    cfg = load_config(path)
    assert not cfg.geometry.hanging and cfg.geometry.seed_up
    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    assert not ws.hanging
    assert cfg.sim.enabled and cfg.sim.plant == "physical"
    assert all(r.cable_ea_n is not None for r in cfg.reels)
    assert cfg.homing.power_up_position_m is not None
    assert ws.check_target(cfg.homing.power_up_position_m) is None


def test_hangprinter_v4_check_config(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["check-config", str(HP4)])
    out, err = capsys.readouterr()
    assert code == exitcodes.OK, err
    assert "workspace  among the anchors: their hull shrunk by 0.08 m across the plan view" in out
    m = re.search(
        r"volume     ([0-9.]+) m³ .*payload is held within the tension limits in ([0-9.]+) %", out
    )
    assert m is not None, out
    assert 1.0 < float(m.group(1)) < 2.5  # the pyramid above the bed, within 0.9 m
    assert float(m.group(2)) > 90.0


def text_with(path: Path, **limits: str) -> str:
    text = path.read_text()
    for k, v in limits.items():
        text, n = re.subn(rf"(?m)^{k} = [^\n#]*", f"{k} = {v}", text)
        if n == 0:
            text = text.replace("[limits]\n", f"[limits]\n{k} = {v}\n")
    return text


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "robot.toml"
    p.write_text(text)
    return p


def test_layouts_that_cannot_work_are_refused(tmp_path: Path) -> None:
    # the anchors all below the floor (not in one plane): nothing among them to work in
    with pytest.raises(ConfigError, match=r"limits\.floor_z_m: 2\.5 m must be below the highest"):
        load_config(write(tmp_path, text_with(HP4, floor_z_m="2.5")))
    # nine cables
    text = HP5.read_text()
    extra = text[text.index("[[reels]]                       # A, low") :]
    extra = extra.replace("node_id = 0", "node_id = 10").replace("node_id = 1\n", "node_id = 11\n")
    extra = extra.replace("node_id = 2", "node_id = 12").replace("node_id = 3", "node_id = 13")
    extra = extra.replace("node_id = 4", "node_id = 14")
    more = text + "\n" + extra.replace("-0.118]", "-0.2]")
    with pytest.raises(ConfigError, match=r"reels: 10 reels: a point effector takes 3 to 8"):
        load_config(write(tmp_path, more))
    # two anchors on one point
    same = HP4.read_text().replace("[1.31422, 1.26814, -0.12128]", "[0.0, -1.61098, -0.13153]")
    with pytest.raises(ConfigError, match=r"anchors 1 and 2 coincide"):
        load_config(write(tmp_path, same))
    # anchors in one plane and a floor above it: the hanging rule's words
    level = HP4.read_text().replace("[0.0, 0.0, 2.29983]", "[0.0, 0.0, -0.125]")
    level = level.replace("-0.13153]", "-0.125]").replace("-0.12128]", "-0.125]")
    level = level.replace("-0.12182]", "-0.125]")
    with pytest.raises(ConfigError, match=r"floor_z_m: 0 m must be below the lowest anchor"):
        load_config(write(tmp_path, level))


def test_a_layout_that_holds_the_payload_nowhere_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Lines that may pull at most 6 N cannot lift 1 kg anywhere: check-config says so."""
    text = text_with(HP4, max_tension_n="6.0", tension_margin_n="0.5")
    text = re.sub(r"(?m)^power_up_position_m = .*$", "", text)
    text = text.replace('plant = "physical"', 'plant = "kinematic"')
    path = write(tmp_path, text)
    code = main(["check-config", str(path)])
    out, err = capsys.readouterr()
    assert out == ""
    assert code == exitcodes.REFUSED
    assert "cannot hold the 1 kg payload anywhere in the workspace" in err
    assert "not a valid robot configuration" in err
