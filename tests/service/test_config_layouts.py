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
    # the reason is the lines' limit, not the layout: the cable and its tension where the
    # tensions come closest to it
    assert "do not surround" not in err
    m = re.search(
        r"where they come closest, at \(([-0-9., ]+)\) m, cable \d tension [-0-9.]+ N "
        r"(above 5\.5 N \(limits\.max_tension_n 6 N|below 3\.5 N \(min_tension_n 3 N) ",
        err,
    )
    assert m is not None, err
    cfg = load_config(HP4)
    at = tuple(float(v) for v in m.group(1).split(","))
    assert Workspace.from_limits(cfg.limits, cfg.geometry).check_point(at) is None


def test_check_config_shows_the_stretch_inside_the_pyramid(tmp_path: Path) -> None:
    """The stretch line's poses on the workspace's centre line: at the narrow top of the
    anchors' pyramid the centre line leaves the workspace, and the nearest sampled point
    inside stands in (outside, the statics there pushes on lines: negative stretch)."""
    from controller.cli.configs import describe

    cfg = load_config(write(tmp_path, text_with(HP4, top_margin_m="0.1")))
    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    (x_lo, x_hi), (y_lo, y_hi), (_, top) = ws.box()
    assert ws.check_point(((x_lo + x_hi) / 2, (y_lo + y_hi) / 2, top)) is not None
    lines, _, data = describe(cfg)
    assert [p["pose"] for p in data["stretch"]] == ["power-up", "floor", "middle", "top"]
    for p in data["stretch"]:
        assert ws.check_point(p["position_m"]) is None, p
        assert max(p["stretch_m"]) > 1e-3, p  # tens of newtons on metres of EA 20 kN line
    (line,) = [ln for ln in lines if ln.startswith("stretch")]
    assert "e-1" not in line and "-0," not in line, line  # poses to a tenth of a millimetre


def test_a_layout_that_must_hang_says_why(tmp_path: Path) -> None:
    """A Hangprinter-like file (floor above the low anchors) whose anchors cannot surround an
    effector is held to the hanging rule; the floor's refusal says why: the anchors lie in
    one plane, or three anchors (always in one plane)."""
    level = HP4.read_text().replace("[0.0, 0.0, 2.29983]", "[0.2, 0.3, -0.125]")
    for low in ("-0.13153]", "-0.12128]", "-0.12182]"):
        level = level.replace(low, "-0.125]")
    with pytest.raises(ConfigError, match=r"floor_z_m: 0 m must be below the lowest anchor") as e:
        load_config(write(tmp_path, level))
    assert "the effector cannot work among these anchors: the anchors lie in one plane" in str(
        e.value
    )
    text = HP4.read_text()
    three = (
        text[: text.index("[[reels]]                       # C, low")]
        + text[text.index("[[reels]]                       # D, on the ceiling") :]
    )
    with pytest.raises(ConfigError, match=r"3 anchors cannot surround an effector"):
        load_config(write(tmp_path, three))
    # the anchors below the floor, not in one plane: no reason to add
    with pytest.raises(ConfigError, match=r"highest anchor minus top_margin_m \(1\.89983 m\)$"):
        load_config(write(tmp_path, text_with(HP4, floor_z_m="2.5")))
