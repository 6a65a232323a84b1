"""The drive-family registry: names, node id ranges, option tables, lazy imports, and each
family's driver and simulated nodes built through it talking to each other on a `virtual` bus.
"""

from __future__ import annotations

import inspect
import logging
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator

import can
import pytest

from drivers import registry
from drivers.base import AxisReading, ConfigurableDriver, ReelDriver
from drivers.bus import open_bus
from drivers.registry import LoopSettings, SimSettings


def test_family_names_and_the_did_you_mean() -> None:
    assert sorted(registry.FAMILIES) == ["cia402", "odrive"]
    assert registry.family("odrive").title == "ODrive"
    assert registry.DEFAULT_KIND == "odrive"
    with pytest.raises(registry.UnknownFamilyError) as exc:
        registry.family("odrve")
    assert str(exc.value) == (
        "unknown drive family 'odrve'; did you mean 'odrive'? (known: cia402, odrive)"
    )
    with pytest.raises(registry.UnknownFamilyError, match="known: cia402, odrive"):
        registry.family("canopen")


def test_node_id_ranges_are_the_drivers() -> None:
    from drivers.cia402 import driver as cia
    from drivers.odrive import cansimple as cs

    odrive, cia402 = registry.family("odrive"), registry.family("cia402")
    assert (odrive.node_id_min, odrive.node_id_max) == (0, cs.MAX_NODE_ID)
    assert (cia402.node_id_min, cia402.node_id_max) == (1, cia.MAX_NODE_ID)


def test_cia402_options_are_the_driver_keywords_with_its_defaults() -> None:
    from drivers.cia402.driver import CiA402Reels

    params = inspect.signature(CiA402Reels.__init__).parameters
    fam = registry.family("cia402")
    for opt in fam.options:
        assert opt.name in params, opt.name
        default = params[opt.name].default
        if opt.required:
            assert default is inspect.Parameter.empty, opt.name
        else:
            assert opt.default == default, opt.name
    assert fam.option("counts_per_rev").required
    with pytest.raises(KeyError):
        fam.option("period_s")  # the loop's, not an option
    odrive = registry.family("odrive")
    assert [(o.name, o.kind, o.default, o.required, o.gt) for o in odrive.options] == [
        ("velocity_limit_rps", "number", None, False, 0.0),
        ("current_limit_a", "number", None, False, 0.0),
    ]
    from drivers.odrive.driver import ODriveReels

    odrive_params = inspect.signature(ODriveReels.__init__).parameters
    for opt in odrive.options:
        assert odrive_params[opt.name].default is None, opt.name
        assert "pre-tension" in opt.doc


def test_the_registry_imports_no_family_until_used() -> None:
    code = (
        "import sys; import drivers.registry as r; r.family('cia402'); "
        "bad = [m for m in ('can', 'canopen', 'drivers.odrive.driver', 'drivers.cia402') "
        "if m in sys.modules]; print(bad)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True
    )
    assert out.stdout.strip() == "[]", out


@pytest.fixture
def channel() -> Iterator[tuple[can.BusABC, can.BusABC]]:
    name = f"test-registry-{uuid.uuid4().hex}"
    sim_bus, bus = open_bus("virtual", name), open_bus("virtual", name)
    yield sim_bus, bus
    bus.shutdown()
    sim_bus.shutdown()


def _poll_until(driver: ReelDriver, cond: Callable[[], bool], timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        driver.poll()
        if cond():
            return True
        time.sleep(0.001)
    return False


@pytest.mark.parametrize(
    ("kind", "nodes", "options", "cls"),
    [
        ("odrive", (0, 1, 2), {}, "ODriveReels"),
        ("cia402", (1, 2, 3), {"counts_per_rev": 4096.0}, "CiA402Reels"),
    ],
)
def test_each_family_driver_arms_its_own_simulated_nodes(
    channel: tuple[can.BusABC, can.BusABC],
    kind: str,
    nodes: tuple[int, ...],
    options: dict[str, float],
    cls: str,
) -> None:
    sim_bus, bus = channel
    fam = registry.family(kind)
    start = (0.5, -1.0, 2.25)
    bank = fam.sim_bank(sim_bus, nodes, options, SimSettings(start)).start()
    try:
        assert bank.thread is not None and bank.thread.is_alive()
        driver = fam.open_driver(bus, nodes, options, LoopSettings(0.002, 0.05))
        assert type(driver).__name__ == cls
        assert isinstance(driver, ReelDriver)
        assert isinstance(driver, ConfigurableDriver) == (kind == "cia402")
        if isinstance(driver, ConfigurableDriver):
            driver.configure()
        r = driver.read()
        assert _poll_until(driver, lambda: all(x.state_name != "unknown" for x in r))
        assert _poll_until(driver, lambda: all(x.stamp_s > -1e9 for x in r))
        assert [round(x.position_rev, 3) for x in r] == list(start)
        assert not any(x.ready for x in r) and all(x.fault is None for x in r)
        driver.arm()
        assert _poll_until(driver, lambda: all(x.ready for x in r)), [x.state_name for x in r]
        driver.estop()
        assert _poll_until(driver, lambda: not any(x.ready for x in r))
        assert bank.axis(nodes[1]) is not None
    finally:
        assert bank.stop()
    assert bank.thread is not None and not bank.thread.is_alive()


def test_odrive_factory_takes_the_loop_settings_and_refuses_unknown_options(
    channel: tuple[can.BusABC, can.BusABC],
) -> None:
    _sim_bus, bus = channel
    fam = registry.family("odrive")
    d = fam.open_driver(bus, (0, 1), {}, LoopSettings(0.001, 0.08, encoder_rtr=True))
    assert d._catch_up_age_s == 0.04  # type: ignore[attr-defined]
    assert d._encoder_rtr is True  # type: ignore[attr-defined]
    assert d.velocity_limit_rps is None and d.current_limit_a is None  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="no \\[drive\\] options named \\['counts_per_rev'\\]"):
        fam.open_driver(bus, (0,), {"counts_per_rev": 1.0}, LoopSettings(0.001, 0.08))
    with pytest.raises(ValueError, match="known: current_limit_a, velocity_limit_rps"):
        fam.open_driver(
            bus, (0,), {"velocity_limit_rps": 5.0, "gain": 2}, LoopSettings(0.001, 0.08)
        )
    with pytest.raises(ValueError, match=r"outside 0\.\.63"):
        fam.open_driver(bus, (64,), {}, LoopSettings(0.001, 0.08))


def test_cia402_factory_passes_its_options_and_the_loop_period(
    channel: tuple[can.BusABC, can.BusABC],
) -> None:
    _sim_bus, bus = channel
    fam = registry.family("cia402")
    d = fam.open_driver(
        bus,
        (5,),
        {"counts_per_rev": 1000.0, "heartbeat_period_s": 0.05, "velocity_units_per_rps": 10.0},
        LoopSettings(0.004, 0.05),
    )
    assert d.counts_per_rev == 1000.0 and d.period_s == 0.004  # type: ignore[attr-defined]
    assert d._heartbeat_ms == 50 and d._velocity_units_per_rps == 10.0  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match="counts_per_rev"):
        fam.open_driver(bus, (5,), {}, LoopSettings(0.004, 0.05))
    with pytest.raises(ValueError, match="unknown CiA 402"):
        fam.open_driver(bus, (5,), {"counts_per_rev": 1.0, "gain": 2}, LoopSettings(0.004, 0.05))
    with pytest.raises(ValueError, match=r"outside 1\.\.127"):
        fam.open_driver(bus, (0,), {"counts_per_rev": 1.0}, LoopSettings(0.004, 0.05))


def test_cia402_checks_name_the_key(tmp_path: object) -> None:
    from pathlib import Path

    from drivers.cia402.driver import EDS_PATH

    fam = registry.family("cia402")
    assert fam.check_options({"counts_per_rev": 1.0, "eds": str(EDS_PATH)}, 0.002) == []
    assert registry.family("odrive").check_options({}, 1 / 300) == []
    (key, problem), *_ = fam.check_options({"counts_per_rev": 1.0}, 1 / 300)
    assert key == "loop.rate_hz" and "interpolation time period" in problem
    assert isinstance(tmp_path, Path)
    bad = tmp_path / "bad.eds"
    bad.write_text("this is not an EDS\n")
    [(key, problem)] = fam.check_options({"eds": str(bad)}, 0.002)
    assert key == "drive.eds" and problem.startswith("not a usable EDS"), problem
    # An EDS without the velocity offset object: refused only while the offset is used.
    lean = tmp_path / "lean.eds"
    text = EDS_PATH.read_text()
    start = text.index("[60B1]")
    end = text.index("\n[", start + 1)
    lean.write_text(text[:start] + text[end + 1 :])
    [(key, problem)] = fam.check_options({"eds": str(lean)}, 0.002)
    assert (key, problem) == ("drive.eds", "lacks objects the driver uses: 0x60B1")
    assert fam.check_options({"eds": str(lean), "velocity_offset": False}, 0.002) == []


def test_odrive_startup_notes() -> None:
    fam = registry.family("odrive")
    closed = AxisReading(3, axis_state=8)
    assert fam.note_first_heartbeat(closed, armed=True) is None
    level, text = fam.note_first_heartbeat(closed, armed=False) or (0, "")
    assert level == logging.WARNING and text.startswith("ODrive node 3 is in closed loop")
    stopped = AxisReading(1, axis_state=1, axis_error=0x1000000)
    level, text = fam.note_first_heartbeat(stopped, armed=False) or (0, "")
    assert level == logging.INFO and "WATCHDOG_TIMER_EXPIRED" in text
    assert fam.note_first_heartbeat(AxisReading(2, axis_state=1), armed=False) is None
    assert registry.family("cia402").note_first_heartbeat(closed, armed=False) is None
