"""The loop bench's drive families: its robot on CiA 402 drives is a valid configuration."""

from __future__ import annotations

from controller.cli import bench
from controller.service.config import parse_config


def test_loop_bench_robot_on_each_family() -> None:
    odrive = parse_config(bench.loop_config_data(500.0, 7447), "odrive")
    assert (odrive.drive.kind, odrive.node_ids) == ("odrive", (0, 1, 2, 3))
    cia = parse_config(bench.loop_config_data(bench.CIA402_RATE_HZ, 7447, "cia402"), "cia402")
    assert (cia.drive.kind, cia.node_ids) == ("cia402", (1, 2, 3, 4))
    assert cia.drive.options["counts_per_rev"] == bench.CIA402_COUNTS_PER_REV
    assert cia.loop.rate_hz == 500.0 and cia.bus.interface == "udp_multicast"
    assert not cia.sim.enabled  # the bench serves the drives from a process of its own
