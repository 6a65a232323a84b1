"""Configuration: shipped files load, defaults, and one error message per class of mistake."""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from controller.core.kinematics import ipk_point
from controller.service.config import (
    ConfigError,
    RobotConfig,
    default_config,
    load_config,
    paper_robot_data,
    parse_config,
)

REPO = Path(__file__).resolve().parents[2]
PAPER = REPO / "config" / "paper-acre.toml"
DESK = REPO / "config" / "desk.toml"


def test_default_config_is_the_paper_robot_on_simulated_reels() -> None:
    cfg = default_config()
    assert load_config(None) == cfg
    assert cfg.name == "default"
    assert cfg.source == "<built-in default>"
    assert cfg.node_ids == (0, 1, 2, 3)
    assert cfg.anchors_m == (
        (-40.45, -25.0, 7.62),
        (-40.45, 25.0, 7.62),
        (40.45, 25.0, 7.62),
        (40.45, -25.0, 7.62),
    )
    assert cfg.bus.interface == "virtual"
    assert cfg.sim.enabled
    assert cfg.homing.power_up_position_m == (0.0, 0.0, 2.0)
    assert cfg.homing.state_file is None
    assert cfg.zenoh.prefix == "cablebot/default"
    assert cfg.zenoh.listen == ("tcp/127.0.0.1:7447",)
    assert cfg.loop.rate_hz == 500.0
    lim = cfg.limits
    assert (lim.max_speed_mps, lim.max_accel_mps2, lim.xy_margin_m) == (2.0, 1.0, 2.0)
    # 0.05 m of cable per motor turn
    assert cfg.reels[0].reel.length_m(20.0) - cfg.reels[0].reel.length_m(0.0) == pytest.approx(1.0)
    json.dumps(cfg.summary(), allow_nan=False)  # JSON-able


def test_paper_acre_file_matches_the_paper() -> None:
    cfg = load_config(PAPER)
    assert cfg.name == "paper-acre"
    assert cfg.source == str(PAPER)
    xs = sorted({a[0] for a in cfg.anchors_m})
    ys = sorted({a[1] for a in cfg.anchors_m})
    assert xs[1] - xs[0] == pytest.approx(80.9)
    assert ys[1] - ys[0] == pytest.approx(50.0)
    assert {a[2] for a in cfg.anchors_m} == {7.62}
    assert cfg.bus.interface == "udp_multicast"
    assert dict(cfg.bus.options) == {"port": 43113}
    assert cfg.bus.as_mapping() == {
        "interface": "udp_multicast",
        "channel": "239.74.0.1",
        "port": 43113,
    }
    assert not cfg.sim.enabled
    assert cfg.homing.state_file is not None
    assert cfg.homing.state_file.endswith("/.local/state/cablebot/paper-acre-offsets.json")
    assert "~" not in cfg.homing.state_file
    # the paper's example (a): 48 m cables meet at (0, 0, 1.14)
    lengths = ipk_point(cfg.geometry, (0.0, 0.0, 7.62 - math.sqrt(48**2 - 40.45**2 - 25**2)))
    assert lengths == pytest.approx((48.0,) * 4)
    json.dumps(cfg.summary(), allow_nan=False)


def test_desk_file() -> None:
    cfg = load_config(DESK)
    assert cfg.name == "desk"
    assert (cfg.bus.interface, cfg.bus.channel, cfg.bus.bitrate) == ("socketcan", "can0", 10**6)
    assert cfg.loop.rate_hz == 500.0  # four ODrives: 1 kHz is more than 1 Mbit/s carries
    assert cfg.zenoh.prefix == "cablebot/desk"
    assert cfg.homing.power_up_position_m is None
    reel = cfg.reels[0].reel
    assert reel.metres_per_rev == pytest.approx(math.pi * 0.030)  # 30 mm drum
    assert cfg.reels[2].reel.direction == -1
    assert cfg.limits.xy_margin_m < 0.1


def base() -> dict[str, Any]:
    return paper_robot_data("t")


def parse(data: dict[str, Any]) -> RobotConfig:
    return parse_config(data, "robot.toml")


def err(data: dict[str, Any]) -> str:
    with pytest.raises(ConfigError) as info:
        parse(data)
    msg = str(info.value)
    assert msg.startswith("robot.toml: "), msg  # names the file
    return msg


def edit(path: str, value: Any) -> dict[str, Any]:
    """A copy of the base data with `path` (dots, [i]) set to value; value DELETE removes it."""
    data = copy.deepcopy(base())
    node: Any = data
    parts = path.replace("[", ".").replace("]", "").split(".")
    for p in parts[:-1]:
        node = node[int(p)] if p.isdigit() else node.setdefault(p, {})
    last = parts[-1]
    if value is DELETE:
        del node[int(last) if last.isdigit() else last]
    else:
        node[int(last) if last.isdigit() else last] = value
    return data


DELETE = object()


def test_base_data_is_valid() -> None:
    cfg = parse(base())
    assert cfg.name == "t"
    assert cfg.zenoh.prefix == "cablebot/t"


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        # unknown keys, with hints
        ("limits.max_speed", 2.0, "limits.max_speed: unknown key; did you mean 'max_speed_mps'?"),
        ("limits.max_speed_kph", 7.0, "limits.max_speed_kph: unknown key; did you mean"),
        (
            "reels[1].gear_ration",
            2.0,
            "reels[1].gear_ration: unknown key; did you mean 'gear_ratio'",
        ),
        ("colour", "red", "colour: unknown key"),
        ("limit.max_speed_mps", 1.0, "limit: unknown key; did you mean 'limits'?"),
        ("loop.rate", 100.0, "loop.rate: unknown key; did you mean 'rate_hz'"),
        ("zenoh.listen_port", 7447, "zenoh.listen_port: unknown key"),
        # wrong unit / type
        (
            "limits.max_speed_mps",
            "2 m/s",
            "limits.max_speed_mps: must be a number in metres per second",
        ),
        ("faults.stale_timeout_s", "50ms", "faults.stale_timeout_s: must be a number in seconds"),
        ("loop.realtime", "yes", "loop.realtime: must be true or false"),
        ("reels[0].node_id", 1.5, "reels[0].node_id: must be an integer"),
        ("reels[0].node_id", True, "reels[0].node_id: must be an integer"),
        ("reels[0].anchor_m", [1.0, 2.0], "reels[0].anchor_m: must be [x, y, z] in metres"),
        ("bus", "can0", "bus: must be a table"),
        ("reels", {"node_id": 1}, "reels: must be an array of tables"),
        # ranges
        ("reels[2].metres_per_rev", -0.1, "reels[2].metres_per_rev: must be > 0, got -0.1"),
        ("reels[0].gear_ratio", 0, "reels[0].gear_ratio: must be > 0, got 0"),
        ("reels[0].direction", 2, "reels[0].direction: must be 1 or -1, got 2"),
        ("reels[3].node_id", 64, "reels[3].node_id: must be <= 63, got 64"),
        ("reels[3].node_id", -1, "reels[3].node_id: must be >= 0, got -1"),
        ("loop.rate_hz", 5000.0, "loop.rate_hz: must be <= 2000, got 5000.0"),
        ("loop.rate_hz", 0.5, "loop.rate_hz: must be >= 1, got 0.5"),
        ("loop.publish_every", 0, "loop.publish_every: must be >= 1"),
        ("loop.rt_priority", 100, "loop.rt_priority: must be <= 99"),
        ("limits.max_accel_mps2", 0.0, "limits.max_accel_mps2: must be > 0"),
        ("limits.xy_margin_m", math.inf, "limits.xy_margin_m: must be finite"),
        ("limits.xy_margin_m", math.nan, "limits.xy_margin_m: must be finite"),
        ("limits.junction_deviation_m", 0.0, "limits.junction_deviation_m: must be > 0"),
        ("limits.max_queued_points", 999, "limits.max_queued_points: must be >= 1000, got 999"),
        ("limits.max_queued_points", 10**8, "limits.max_queued_points: must be <= 10000000"),
        ("limits.max_queued_points", 5e4, "limits.max_queued_points: must be an integer"),
        ("zenoh.mode", "server", "zenoh.mode: must be one of peer, client, router"),
        ("zenoh.prefix", "cablebot/*", "zenoh.prefix: must be a plain key expression"),
        ("zenoh.listen", ["7447"], "zenoh.listen: endpoint '7447' must look like"),
        ("zenoh.config_file", "/nonexistent/z.json5", "zenoh.config_file: no such file"),
        ("name", "my robot", "name: must match"),
        ("bus.bitrate", 5, "bus.bitrate: must be >= 10000"),
        ("bus.options", {"channel": "x"}, "bus.options.channel: set it as bus.channel"),
        ("homing.state_file", "/tmp/{robot}.json", "homing.state_file: only {name} may be"),
        # missing
        ("reels[0].node_id", DELETE, "reels[0].node_id: missing (required)"),
        ("reels[0].metres_per_rev", DELETE, "reels[0]: give exactly one of metres_per_rev"),
        ("reels[0].drum_radius_m", 0.1, "reels[0]: give exactly one of metres_per_rev"),
        ("limits.min_cable_m", DELETE, "limits.min_cable_m: missing (required)"),
        ("limits", DELETE, "limits: missing (every robot needs its own [limits])"),
        ("reels", DELETE, "reels: missing"),
        # cross-checks
        ("reels[3].node_id", 1, "reels[3].node_id: duplicate node id 1 (also reels[1])"),
        ("limits.floor_z_m", 7.0, "limits.floor_z_m: 7 m must be below the lowest anchor"),
        ("limits.min_cable_m", 200.0, "limits.min_cable_m: 200 m must be < max_cable_m"),
        ("limits.default_speed_mps", 3.0, "limits.default_speed_mps: 3 m/s exceeds max_speed_mps"),
        ("limits.xy_margin_m", 30.0, "limits.xy_margin_m: 30 m leaves no workspace"),
        (
            "faults.stale_timeout_s",
            0.003,
            "faults.stale_timeout_s: 0.003 s is shorter than two loop",
        ),
        (
            "sim.encoder_period_s",
            0.3,
            "faults.stale_timeout_s: 0.5 s is shorter than two simulated",
        ),
        ("faults.heartbeat_timeout_s", 0.15, "faults.heartbeat_timeout_s: 0.15 s is shorter"),
        (
            "homing.power_up_position_m",
            [0.0, 0.0, 7.5],
            "homing.power_up_position_m: z=7.5 m is above the anchor plane minus margin (6.62 m)",
        ),
        (
            "homing.power_up_position_m",
            [39.5, 0.0, 2.0],
            "homing.power_up_position_m: (39.5, 0) m is outside the anchors' plan-view polygon",
        ),
        ("limits.max_cable_m", 2000.0, "reels[0]: float32 motor turns resolve only 0.195 mm"),
    ],
)
def test_error_messages_name_the_key_and_the_problem(path: str, value: Any, expected: str) -> None:
    msg = err(edit(path, value))
    assert expected in msg, msg


def test_too_few_reels_and_singular_anchors() -> None:
    data = base()
    data["reels"] = data["reels"][:2]
    assert "reels: need at least 3 reels, got 2" in err(data)
    data = base()
    for i, r in enumerate(data["reels"][:3]):
        r["anchor_m"] = [float(i), float(i), 7.62]  # collinear in plan view
    data["reels"] = data["reels"][:3]
    msg = err(data)
    assert "reels[*].anchor_m: singular anchors" in msg and "collinear" in msg, msg
    data = base()
    data["reels"][2]["anchor_m"] = data["reels"][0]["anchor_m"]
    msg = err(data)
    assert "anchors 1 and 3 coincide" in msg, msg


def test_spool_buildup_options() -> None:
    data = edit("reels[0].cable_diameter_m", 0.002)
    data["reels"][0]["turns_per_layer"] = 40.0
    data["reels"][0]["reference_length_m"] = 48.0
    cfg = parse(data)
    assert cfg.reels[0].reel.spool_buildup_m_per_rev2 == pytest.approx(2 * math.pi * 0.002 / 40)
    data["reels"][0]["spool_buildup_m_per_rev2"] = 0.001
    assert "give either spool_buildup_m_per_rev2 or cable_diameter_m" in err(data)
    # a build-up so strong that the spool empties before max_cable_m
    data = edit("reels[0].spool_buildup_m_per_rev2", 0.01)
    assert "reels[0]: cannot cover limits.min_cable_m..max_cable_m" in err(data)


def test_spool_buildup_factor() -> None:
    """RepRapFirmware's area factor (M666 Q x O, in metres) is the same build-up as
    spool_buildup_m_per_rev2 = 2 pi^2 x factor, and is one of the three ways to give it."""
    data = edit("reels[0].spool_buildup_factor_m", 1.5e-6)
    data["reels"][0]["reference_length_m"] = 48.0
    cfg = parse(data)
    assert cfg.reels[0].reel.spool_buildup_m_per_rev2 == pytest.approx(
        2 * math.pi**2 * 1.5e-6, rel=1e-15
    )
    assert cfg.reels[1].reel.spool_buildup_m_per_rev2 == 0.0
    for other, value in (("spool_buildup_m_per_rev2", 0.001), ("cable_diameter_m", 0.002)):
        both = copy.deepcopy(data)
        both["reels"][0][other] = value
        assert "give either spool_buildup_factor_m or " in err(both)
    for bad, why in (
        (-1e-4, "must be >= 0"),
        ("0.1 mm", "must be a number"),
        (math.nan, "must be finite"),
    ):
        msg = err(edit("reels[0].spool_buildup_factor_m", bad))
        assert f"reels[0].spool_buildup_factor_m: {why}" in msg, msg


def test_defaults_of_optional_sections() -> None:
    data = base()
    for section in ("bus", "loop", "faults", "homing", "zenoh", "sim"):
        data.pop(section, None)
    del data["name"]
    cfg = parse(data)
    assert cfg.name == "default"
    assert cfg.zenoh.prefix == "cablebot/default"
    assert cfg.bus.interface == "virtual"
    assert cfg.sim.enabled  # nothing else could answer on a virtual bus
    assert cfg.homing.power_up_position_m is None
    assert cfg.homing.state_file is None
    assert cfg.loop.auto_arm is None
    data["bus"] = {"interface": "socketcan", "channel": "can1"}
    assert not parse(data).sim.enabled


def test_state_file_expansion() -> None:
    cfg = parse(edit("homing.state_file", "~/x/{name}.json"))
    assert cfg.homing.state_file == str(Path("~/x/t.json").expanduser())


def test_load_config_file_errors(tmp_path: Path) -> None:
    missing = tmp_path / "nope.toml"
    with pytest.raises(ConfigError, match=r"nope\.toml: cannot read"):
        load_config(missing)
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n[limits\n")
    with pytest.raises(ConfigError, match=r"bad\.toml: not valid TOML"):
        load_config(bad)
    typo = tmp_path / "typo.toml"
    typo.write_text(PAPER.read_text().replace("max_cable_m = 100.0", "max_cabel_m = 100.0"))
    with pytest.raises(ConfigError) as info:
        load_config(typo)
    assert str(info.value).startswith(f"{typo}: limits.max_cabel_m: unknown key")


def test_config_error_is_a_value_error_with_fields() -> None:
    with pytest.raises(ValueError) as info:
        parse(edit("reels[2].metres_per_rev", -0.1))
    e = info.value
    assert isinstance(e, ConfigError)
    assert (e.source, e.key) == ("robot.toml", "reels[2].metres_per_rev")
    assert str(e) == "robot.toml: reels[2].metres_per_rev: must be > 0, got -0.1"


def test_systemd_unit_is_type_notify_with_watchdog() -> None:
    import configparser

    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.optionxform = str  # type: ignore[assignment,method-assign]
    unit.read(REPO / "config" / "cablebot@.service")
    svc = unit["Service"]
    assert svc["Type"] == "notify"
    assert svc["NotifyAccess"] == "main"
    assert svc["WatchdogSec"] == "2s"
    assert "cablebot run --config" in svc["ExecStart"]
    assert unit["Install"]["WantedBy"] == "multi-user.target"


# ---------------------------------------------------------------------------- hostile files


def test_a_file_that_is_not_utf8_is_a_config_error_naming_line_and_byte(tmp_path: Path) -> None:
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(PAPER.read_bytes().replace(b'name = "paper-acre"', b'name = "caf\xe9"'))
    with pytest.raises(ConfigError) as info:
        load_config(bad)
    msg = str(info.value)
    assert msg.startswith(f"{bad}: not UTF-8 text: byte 0xe9 at line "), msg


@pytest.mark.parametrize(
    ("path", "value", "expected"),
    [
        ("reels[0].anchor_m", [1e308, -1e308, 7.62], "reels[0].anchor_m: coordinates must be"),
        ("reels[0].anchor_m", [10**400, 0, 7.62], "reels[0].anchor_m: must be finite"),
        ("limits.max_cable_m", 1e308, "limits.max_cable_m: must be within ±1e+09"),
        ("limits.floor_z_m", -1e308, "limits.floor_z_m: must be within ±1e+09"),
        ("limits.max_speed_mps", 10**400, "limits.max_speed_mps: must be finite"),
        ("homing.power_up_position_m", [0.0, 1e300, 2.0], "homing.power_up_position_m: coord"),
        ("loop.publish_every", 10**400, "loop.publish_every: must be <= 100000"),
    ],
)
def test_extreme_numbers_are_config_errors_not_tracebacks(
    path: str, value: Any, expected: str
) -> None:
    msg = err(edit(path, value))
    assert expected in msg, msg


def _numeric_paths(node: Any, prefix: str = "") -> list[str]:
    out: list[str] = []
    items = enumerate(node) if isinstance(node, list) else node.items()
    for k, v in items:
        p = f"{prefix}[{k}]" if isinstance(node, list) else (f"{prefix}.{k}" if prefix else k)
        if isinstance(v, bool):
            continue
        if isinstance(v, int | float):
            out.append(p)
        elif isinstance(v, dict) or (isinstance(v, list) and v and isinstance(v[0], dict)):
            out.extend(_numeric_paths(v, p))
        elif isinstance(v, list) and len(v) == 3:
            out.extend(f"{p}[{i}]" for i in range(3))
    return out


@pytest.mark.parametrize("value", [1e308, -1e308, 5e-324, -5e-324, 10**30, -(10**30), 0])
def test_no_number_anywhere_makes_validation_raise_anything_but_config_error(value: Any) -> None:
    paths = _numeric_paths(base())
    assert len(paths) > 40  # every limit, fault, reel number and anchor coordinate
    for path in paths:
        try:
            parse(edit(path, value))
        except ConfigError as exc:
            assert str(exc).startswith("robot.toml: "), (path, str(exc))


def test_zenoh_listen_port_out_of_range_names_the_key() -> None:
    msg = err(edit("zenoh.listen", ["tcp/127.0.0.1:99999"]))
    assert "zenoh.listen: endpoint 'tcp/127.0.0.1:99999': port must be 0..65535" in msg, msg
    msg = err(edit("zenoh.connect", ["tcp/10.0.0.1:0"]))
    assert "zenoh.connect: endpoint 'tcp/10.0.0.1:0': port must be 1..65535" in msg, msg
    msg = err(edit("zenoh.connect", ["tcp/10.0.0.1"]))
    assert "zenoh.connect: endpoint 'tcp/10.0.0.1' must look like 'tcp/HOST:PORT'" in msg, msg
    cfg = parse(edit("zenoh.listen", ["tcp/[::1]:7447", "unixsock-stream//tmp/z.sock"]))
    assert cfg.zenoh.listen == ("tcp/[::1]:7447", "unixsock-stream//tmp/z.sock")


def test_a_garbage_zenoh_file_is_a_config_error_naming_the_key(tmp_path: Path) -> None:
    garbage = tmp_path / "z.json5"
    garbage.write_text("{ this is : not json5 ,,, }")
    msg = err(edit("zenoh.config_file", str(garbage)))
    assert "zenoh.config_file: not a valid Zenoh configuration" in msg, msg
    bad_port = tmp_path / "port.json5"
    bad_port.write_text('{ listen: { endpoints: ["tcp/127.0.0.1:99999"] } }')
    msg = err(edit("zenoh.config_file", str(bad_port)))
    assert "zenoh.config_file: listen: endpoint 'tcp/127.0.0.1:99999': port must be" in msg, msg
    good = tmp_path / "good.json5"
    good.write_text('{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:7447"] } }')
    assert parse(edit("zenoh.config_file", str(good))).zenoh.config_file == str(good)


def test_unknown_bus_interface_is_caught_by_validation() -> None:
    msg = err(edit("bus.interface", "sockectan"))
    assert "bus.interface: unknown python-can interface 'sockectan'; did you mean 'socketcan'?" in (
        msg
    ), msg
    assert "udp_multicast" in msg  # the known names are listed


def test_bus_options_are_checked_against_the_interface() -> None:
    data = edit("bus", {"interface": "udp_multicast", "channel": "239.74.0.1"})
    data["bus"]["options"] = {"prot": 43113, "hop_limit": 0}
    msg = err(data)
    assert (
        "bus.options.prot: not an option of the udp_multicast interface; did you mean 'port'?"
        in (msg)
    ), msg
    assert "hop_limit" not in msg.split("(it takes")[0]
    data["bus"]["options"] = {"port": 43113, "hop_limit": 0, "receive_own_messages": False}
    cfg = parse(data)
    assert dict(cfg.bus.options) == {"port": 43113, "hop_limit": 0, "receive_own_messages": False}
    data = edit("bus.options", {"rx_queue_size": 100, "preserve_timestamps": True})
    assert dict(parse(data).bus.options)["rx_queue_size"] == 100  # virtual's own keywords
    msg = err(edit("bus.options", {"bogus": 1}))
    assert "bus.options.bogus: not an option of the virtual interface" in msg, msg


def test_every_problem_is_reported_at_once() -> None:
    data = edit("limits.max_speed", 2.0)  # typo: unknown key
    data["reels"][2]["metres_per_rev"] = -0.1
    data["loop"]["rate_hz"] = "fast"
    data["zenoh"] = {"listen": ["tcp/127.0.0.1:99999"]}
    data["bus"] = {"interface": "virtual", "channel": "x", "options": {"bogus": 1}}
    with pytest.raises(ConfigError) as info:
        parse(data)
    e = info.value
    lines = str(e).splitlines()
    assert len(e.errors) == len(lines) == 5, str(e)
    assert all(line.startswith("robot.toml: ") for line in lines), lines
    keys = [x.key for x in e.errors]
    assert keys == [
        "reels[2].metres_per_rev",
        "bus.options.bogus",
        "loop.rate_hz",
        "limits.max_speed",
        "zenoh.listen",
    ], keys
    assert (e.key, e.problem) == (e.errors[0].key, e.errors[0].problem)


def test_simulated_watchdog_timeout_is_validated() -> None:
    assert parse(base()).sim.watchdog_timeout_s == 1.0  # the built-in robot sets it
    unset = base()
    del unset["sim"]["watchdog_timeout_s"]
    assert parse(unset).sim.watchdog_timeout_s == 0.3
    assert parse(edit("sim.watchdog_timeout_s", 0.0)).sim.watchdog_timeout_s == 0.0
    msg = err(edit("sim.watchdog_timeout_s", 0.005))
    assert "sim.watchdog_timeout_s: 0.005 s is shorter than 3 loop periods" in msg, msg
    # unset: 0.3 s, or 5 loop periods on a slow loop
    slow = edit("loop.rate_hz", 10.0)
    slow["faults"]["stale_timeout_s"] = 0.5
    del slow["sim"]["watchdog_timeout_s"]
    assert parse(slow).sim.watchdog_timeout_s == 0.5
    msg = err(edit("sim.watchdog_timeout_s", -1.0))
    assert "sim.watchdog_timeout_s: must be >= 0" in msg, msg


# ------------------------------------------------------------------------------ [drive]


def cia402(**drive: Any) -> dict[str, Any]:
    """The base robot on CiA 402 drives with node ids 1..4 (and `drive` keys on top)."""
    data = base()
    data["drive"] = {"kind": "cia402", "counts_per_rev": 131072, **drive}
    for i, reel in enumerate(data["reels"]):
        reel["node_id"] = i + 1
    return data


def cia402_edit(path: str, value: Any) -> dict[str, Any]:
    data = cia402()
    node: Any = data
    parts = path.replace("[", ".").replace("]", "").split(".")
    for p in parts[:-1]:
        node = node[int(p)] if p.isdigit() else node.setdefault(p, {})
    last = parts[-1]
    if value is DELETE:
        del node[int(last) if last.isdigit() else last]
    else:
        node[int(last) if last.isdigit() else last] = value
    return data


def test_drive_defaults_to_odrive_without_options() -> None:
    cfg = default_config()
    assert (cfg.drive.kind, dict(cfg.drive.options)) == ("odrive", {})
    assert cfg.summary()["drive"] == {"kind": "odrive", "options": {}}
    assert parse(edit("drive.kind", "odrive")).drive == cfg.drive


def test_cia402_drive_options_get_the_registry_defaults() -> None:
    cfg = parse(cia402())
    assert cfg.drive.kind == "cia402"
    assert cfg.node_ids == (1, 2, 3, 4)
    assert dict(cfg.drive.options) == {
        "counts_per_rev": 131072.0,
        "velocity_offset": True,
        "torque": True,
        "heartbeat_period_s": 0.1,
        "sdo_timeout_s": 0.3,
    }
    from drivers.cia402.driver import EDS_PATH

    cfg = parse(cia402(velocity_units_per_rps=10.0, eds=str(EDS_PATH), torque=False))
    assert cfg.drive.options["velocity_units_per_rps"] == 10.0
    assert cfg.drive.options["eds"] == str(EDS_PATH)
    assert cfg.drive.options["torque"] is False
    json.dumps(cfg.summary(), allow_nan=False)
    # CANopen node ids reach 127; ODrive's stop at 63.
    assert parse(cia402_edit("reels[3].node_id", 127)).node_ids[3] == 127


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        (
            lambda: edit("drive.kind", "odrve"),
            "drive.kind: unknown drive family 'odrve'; did you mean 'odrive'? "
            "(known: cia402, odrive)",
        ),
        (lambda: edit("drive", "cia402"), "drive: must be a table, got str"),
        (
            lambda: edit("drive.counts_per_rev", 4096),
            "drive.counts_per_rev: unknown key (counts_per_rev is an option of [drive] kind = "
            "'cia402', not 'odrive')",
        ),
        (
            lambda: cia402_edit("drive.count_per_rev", 4096),
            "drive.count_per_rev: unknown key; did you mean 'counts_per_rev'?",
        ),
        (
            lambda: cia402_edit("drive.counts_per_rev", DELETE),
            "drive.counts_per_rev: missing (required)",
        ),
        (
            lambda: cia402_edit("drive.counts_per_rev", "4096 counts"),
            "drive.counts_per_rev: must be a number in units per motor turn (the unit is in "
            "the key name), got '4096 counts'",
        ),
        (lambda: cia402_edit("drive.counts_per_rev", 0), "drive.counts_per_rev: must be > 0"),
        (
            lambda: cia402_edit("drive.heartbeat_period_s", 100.0),
            "drive.heartbeat_period_s: must be <= 65.535, got 100.0",
        ),
        (
            lambda: cia402_edit("drive.sdo_timeout_s", math.nan),
            "drive.sdo_timeout_s: must be finite",
        ),
        (lambda: cia402_edit("drive.torque", "yes"), "drive.torque: must be true or false"),
        (
            lambda: cia402_edit("drive.eds", "/nonexistent/drive.eds"),
            "drive.eds: no such file: /nonexistent/drive.eds",
        ),
        (lambda: cia402_edit("reels[0].node_id", 0), "reels[0].node_id: must be >= 1, got 0"),
        (lambda: cia402_edit("reels[0].node_id", 128), "reels[0].node_id: must be <= 127"),
        (lambda: edit("reels[0].node_id", 100), "reels[0].node_id: must be <= 63, got 100"),
        # cross-checks
        (
            lambda: cia402_edit("loop.rate_hz", 300.0),
            "loop.rate_hz: loop period 0.00333333",
        ),
        (
            lambda: cia402_edit("loop.encoder_rtr", True),
            "loop.encoder_rtr: applies to ODrive drives only",
        ),
        (
            lambda: cia402_edit("drive.heartbeat_period_s", 0.6),
            "faults.heartbeat_timeout_s: 1 s is shorter than two drive heartbeat periods "
            "(drive.heartbeat_period_s = 0.6 s)",
        ),
        (
            lambda: cia402_edit("drive.counts_per_rev", 2**21),
            "reels[0]: 1980 motor turns over limits.min_cable_m..max_cable_m are 4.152e+09 "
            "position counts at drive.counts_per_rev = 2.09715e+06: beyond the drives' 32-bit "
            "position",
        ),
    ],
)
def test_drive_errors_name_the_key_and_the_problem(
    data: Callable[[], dict[str, Any]], expected: str
) -> None:
    msg = err(data())
    assert expected in msg, msg


def test_a_cia402_eds_must_load(tmp_path: Path) -> None:
    bad = tmp_path / "bad.eds"
    bad.write_text("not an EDS\n")
    msg = err(cia402(eds=str(bad)))
    assert "robot.toml: drive.eds: not a usable EDS" in msg, msg
    # The family's own checks run only on a [drive] table that is valid itself.
    assert "drive.eds" not in err(cia402(eds=str(bad), counts_per_rev=-1))


def test_power_up_position_is_judged_by_the_workspace_in_the_words_of_the_keys() -> None:
    from controller.core.workspace import Workspace

    def geometric(data: dict[str, Any]) -> dict[str, Any]:
        """Without a payload the workspace alone judges the pose (the tension rule on the
        power-up pose is tested in test_config_statics.py)."""
        del data["payload"]
        for k in ("min_tension_n", "max_tension_n", "tension_margin_n"):
            del data["limits"][k]
        return data

    data = geometric(edit("homing.power_up_position_m", [0.0, 0.0, -0.5]))
    assert "homing.power_up_position_m: z=-0.5 m is below limits.floor_z_m (0 m)" in err(data)
    data = geometric(edit("homing.power_up_position_m", [-38.45, -23.0, 6.62]))  # near anchor 1
    data["limits"]["min_cable_m"] = 5.0
    msg = err(data)
    assert "homing.power_up_position_m: cable 1 would be 3 m, outside " in msg, msg
    assert "limits.min_cable_m..max_cable_m (5..100 m)" in msg, msg
    data["limits"]["min_cable_m"] = 3.0  # the corner itself: on every boundary, allowed
    cfg = parse(data)
    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    assert cfg.homing.power_up_position_m is not None
    assert ws.check_target(cfg.homing.power_up_position_m) is None
    # what the configuration refuses, the workspace refuses, and the other way round
    for p in ([0.0, 0.0, 6.62 + 1e-6], [38.45 + 1e-6, 0.0, 2.0], [0.0, 23.0, 6.62]):
        refused = ws.check_target(p) is not None
        data = geometric(edit("homing.power_up_position_m", p))
        if refused:
            assert "homing.power_up_position_m" in err(data)
        else:
            assert parse(data).homing.power_up_position_m == tuple(p)


def test_limits_problems_are_reported_together() -> None:
    data = edit("limits.xy_margin_m", 30.0)
    data["limits"]["default_speed_mps"] = 3.0
    msg = err(data)
    assert "limits.xy_margin_m: 30 m leaves no workspace" in msg, msg
    assert "limits.default_speed_mps: 3 m/s exceeds max_speed_mps" in msg, msg
