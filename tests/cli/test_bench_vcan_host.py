"""The controller's compute per tick without transport (`controller.cli.bench_vcan.host_compute`)
and the driver it runs on: it measures ticks of a moving robot, not an idle loop."""

from __future__ import annotations

import math

import pytest

from controller.cli.bench_vcan import NoTransportDriver, host_compute
from drivers.base import ReelDriver


def test_no_transport_driver_is_a_reel_driver_that_follows_its_set_points() -> None:
    d = NoTransportDriver((0, 1), (1.0, 2.0))
    assert isinstance(d, ReelDriver)
    assert d.poll() == 0 and all(r.ready and r.stamp_s > -math.inf for r in d.read())
    d.command([3.0, 4.0])
    assert [r.position_rev for r in d.read()] == [3.0, 4.0]
    with pytest.raises(ValueError):
        d.command([math.nan, 0.0])


def test_host_compute_measures_the_moving_loop() -> None:
    out = host_compute(rate_hz=200.0, seconds=1.0)
    assert out["moves"] >= 1, out  # the robot armed and moved: not an idle loop
    assert out["ticks"] > 20, out
    assert 0.0 < out["compute_p50_s"] <= out["compute_p99_s"] < 1.0, out
