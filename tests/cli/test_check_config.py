"""`cablebot check-config FILE`: what a robot file means, and every problem in it at once."""

from __future__ import annotations

import json
import math
import random
from pathlib import Path

import pytest

from controller.cli import configs as config_cmd
from controller.cli import exitcodes, main
from controller.core.workspace import shrink_polygon
from controller.service.config import ConfigError, load_config

REPO = Path(__file__).resolve().parents[2]


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_desk_file_is_described(capsys: pytest.CaptureFixture[str]) -> None:
    path = str(REPO / "config" / "desk.toml")
    code, out, err = run(capsys, "check-config", path)
    assert code == exitcodes.OK, err
    lines = out.splitlines()
    assert lines[0] == f"robot      'desk' from {path}"
    assert "  cable 1  node  0  anchor (-0.500, -0.500, +0.800) m  94.25 mm/drum turn" in out
    assert "footprint  x -0.500..+0.500 m, y -0.500..+0.500 m, 1.000 m²" in out
    assert (
        "workspace  x -0.450..+0.450 m, y -0.450..+0.450 m, z +0.010..+0.700 m"
        " (footprint shrunk by 0.05 m, 0.810 m²)"
    ) in out
    # the desk file's own comment: anchor to the far bottom corner of the workspace is 1.54 m
    assert "cables     allowed 0.100..1.600 m; the workspace needs 0.122..1.559 m" in out
    assert "loop       500 Hz, pose published at 100 Hz" in out
    assert (
        "statics    payload 0.5 kg, cable tensions 0.5..20 N (maximum from"
        " limits.max_tension_n), commands 0.5 N inside"
    ) in out
    assert "bus        socketcan can0, 1000000 bit/s" in out
    assert "zenoh      peer, listen tcp/127.0.0.1:7447, prefix cablebot/desk" in out
    assert lines[-1] == f"ok: {path} is valid"


def test_config_option_names_the_file_as_for_every_other_verb(
    capsys: pytest.CaptureFixture[str],
) -> None:
    desk = str(REPO / "config" / "desk.toml")
    code, out, err = run(capsys, "check-config", "--config", desk)
    assert code == exitcodes.OK, err
    assert out.splitlines()[-1] == f"ok: {desk} is valid"
    code, out, _ = run(capsys, "check-config", desk, "--config", desk)
    assert code == exitcodes.OK
    paper = str(REPO / "config" / "paper-acre.toml")
    code, out, err = run(capsys, "check-config", desk, "--config", paper)
    assert code == exitcodes.USAGE and out == ""
    assert f"two files, {desk} and --config {paper}: name one" in err
    code, out, err = run(capsys, "check-config")
    assert code == exitcodes.USAGE and "name the robot file" in err


def test_json_description(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "check-config", str(REPO / "config" / "paper-acre.toml"), "--json")
    assert code == exitcodes.OK
    data = json.loads(out)
    assert data["workspace"]["x_m"] == pytest.approx([-38.45, 38.45])
    assert data["workspace"]["z_m"] == pytest.approx([0.0, 6.62])
    assert data["node_ids"] == [0, 1, 2, 3]
    assert data["notes"] == []


def test_every_problem_is_printed_and_exit_is_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = (REPO / "config" / "desk.toml").read_text()
    text = text.replace("rate_hz = 500.0", 'rate_hz = "fast"')
    text = text.replace("max_speed_mps = 0.3", "max_speed_mps = -1")
    text = text.replace("[limits]", "[limits]\nmax_cabel_m = 3")
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(bad)
    code, out, err = run(capsys, "check-config", str(bad))
    assert code == exitcodes.REFUSED
    assert out == ""
    # exactly what the configuration loader reports (every problem it found), then one line
    assert err == f"{info.value}\ncablebot: {bad}: not a valid robot configuration\n"
    assert "loop.rate_hz" in err


def test_missing_and_broken_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "check-config", str(tmp_path / "none.toml"))
    assert code == exitcodes.REFUSED and "cannot read" in err
    broken = tmp_path / "broken.toml"
    broken.write_text("name = \n")
    code, _, err = run(capsys, "check-config", str(broken))
    assert code == exitcodes.REFUSED and "not valid TOML" in err


def test_a_workspace_that_needs_longer_cables_is_noted(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    text = (
        (REPO / "config" / "desk.toml")
        .read_text()
        .replace("max_cable_m = 1.6", "max_cable_m = 1.2")
    )
    f = tmp_path / "short.toml"
    f.write_text(text)
    code, out, _ = run(capsys, "check-config", str(f))
    assert code == exitcodes.OK  # valid, but some of the workspace cannot be reached
    assert "note: parts of the workspace need cables up to 1.559 m, longer than max_cable_m" in out


def test_shrink_polygon_and_area() -> None:
    square = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)]
    inner = shrink_polygon(square, 0.25)
    assert sorted(inner) == sorted([(-0.75, -0.75), (0.75, -0.75), (0.75, 0.75), (-0.75, 0.75)])
    assert config_cmd.polygon_area_m2(inner) == pytest.approx(2.25)
    assert shrink_polygon(square, 1.5) == ()
    tri = [(0.0, 0.0), (4.0, 0.0), (0.0, 3.0)]
    assert config_cmd.polygon_area_m2(shrink_polygon(tri, 0.0)) == pytest.approx(6.0)


def test_workspace_cable_range_matches_sampling() -> None:
    cfg = load_config(REPO / "config" / "desk.toml")
    anchors = [tuple(a) for a in cfg.anchors_m]
    poly = shrink_polygon(cfg.geometry.footprint_m, 0.05)
    lo, hi = config_cmd.workspace_cable_range_m(anchors, poly, 0.01, 0.7)
    rng = random.Random(7)
    seen_lo, seen_hi = math.inf, 0.0
    corners = [(x, y, z) for x in (-0.45, 0.45) for y in (-0.45, 0.45) for z in (0.01, 0.7)]
    samples = [
        (rng.uniform(-0.45, 0.45), rng.uniform(-0.45, 0.45), rng.uniform(0.01, 0.7))
        for _ in range(20_000)
    ]
    for p in samples + corners:
        for a in anchors:
            d = math.dist(a, p)
            seen_lo, seen_hi = min(seen_lo, d), max(seen_hi, d)
    # no point of the workspace needs a cable outside [lo, hi], and both ends are reached
    assert lo == pytest.approx(seen_lo, abs=1e-12) and hi == pytest.approx(seen_hi, abs=1e-12)
    assert lo == pytest.approx(math.dist((-0.5, -0.5, 0.8), (-0.45, -0.45, 0.7)))
    assert hi == pytest.approx(math.dist((-0.5, -0.5, 0.8), (0.45, 0.45, 0.01)))


def _bad_reels(tmp_path: Path) -> Path:
    """desk.toml with reels[0]'s drum radius negative and reels[1] on reels[0]'s node id."""
    lines = (REPO / "config" / "desk.toml").read_text().splitlines(keepends=True)
    radius = [i for i, line in enumerate(lines) if line.startswith("drum_radius_m")]
    node = [i for i, line in enumerate(lines) if line.startswith("node_id")]
    lines[radius[0]] = "drum_radius_m = -0.015\n"
    lines[node[1]] = "node_id = 0\n"
    bad = tmp_path / "bad-reels.toml"
    bad.write_text("".join(lines))
    return bad


def test_a_bad_reel_does_not_hide_a_duplicate_node_id(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = _bad_reels(tmp_path)
    code, _, err = run(capsys, "check-config", str(bad))
    assert code == exitcodes.REFUSED
    assert f"{bad}: reels[0].drum_radius_m: must be > 0, got -0.015\n" in err
    assert f"{bad}: reels[1].node_id: duplicate node id 0 (also reels[0])\n" in err


def test_json_on_an_invalid_file_prints_the_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = _bad_reels(tmp_path)
    code, out, err = run(capsys, "check-config", "--json", str(bad))
    assert code == exitcodes.REFUSED
    report = json.loads(out)
    assert report["ok"] is False and report["file"] == str(bad)
    assert [e["key"] for e in report["errors"]] == ["reels[0].drum_radius_m", "reels[1].node_id"]
    assert report["errors"][1]["problem"] == "duplicate node id 0 (also reels[0])"
    assert "not a valid robot configuration" in err
    latin1 = tmp_path / "latin1.toml"
    latin1.write_bytes('name = "d\xe9sk"\n'.encode("latin-1"))
    code, out, _ = run(capsys, "check-config", "--json", str(latin1))
    assert code == exitcodes.REFUSED
    assert (
        "not UTF-8 text: byte 0xe9 at line 1, column 10" in json.loads(out)["errors"][0]["problem"]
    )
