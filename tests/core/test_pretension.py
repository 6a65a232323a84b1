"""The pre-tension run (pure): ramped torques, stillness, travel and time limits."""

from __future__ import annotations

import math

import pytest

from controller.core.pretension import PretensionRun, PretensionSettings

S = PretensionSettings(
    still_mps=0.002, settle_s=0.5, timeout_s=10.0, max_travel_m=0.3, speed_mps=0.05
)
TENSIONS = (104.4, 90.0, 120.5, 99.0)
LENGTHS = (40.0, 41.0, 42.0, 43.0)


def _run() -> PretensionRun:
    return PretensionRun(S, TENSIONS, LENGTHS, 100.0)


@pytest.mark.parametrize(
    "field", ["still_mps", "settle_s", "timeout_s", "max_travel_m", "speed_mps"]
)
@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_settings_must_be_finite_and_positive(field: str, bad: float) -> None:
    with pytest.raises(ValueError, match=field):
        PretensionSettings(**{field: bad})


def test_run_refuses_mismatched_or_non_finite_inputs() -> None:
    with pytest.raises(ValueError, match="one tension per cable"):
        PretensionRun(S, TENSIONS, LENGTHS[:3], 0.0)
    with pytest.raises(ValueError, match="finite"):
        PretensionRun(S, (math.nan, 0.0, 0.0, 0.0), LENGTHS, 0.0)
    with pytest.raises(ValueError, match="finite"):
        PretensionRun(S, TENSIONS, LENGTHS, math.inf)


def test_still_for_the_settle_time_is_done() -> None:
    run = _run()
    still = (0.0005, -0.001, 0.0, 0.0019)
    t = 100.0
    while not run.done:
        assert run.update(t, LENGTHS, still) is None
        t += 0.01
        assert t < 102.0, "never done"
    assert run.still_after_s == pytest.approx(S.settle_s, abs=0.011)


def test_a_moving_cable_restarts_the_settle_time() -> None:
    run = _run()
    still = (0.0, 0.0, 0.0, 0.0)
    moving = (0.0, 0.0, 0.003, 0.0)
    t = 100.0
    for _ in range(40):  # 0.4 s still
        run.update(t, LENGTHS, still)
        t += 0.01
    run.update(t, LENGTHS, moving)  # at 0.4 s cable 3 moves: stillness starts again
    assert run.worst_mps == pytest.approx(0.003)
    t += 0.01
    while not run.done:
        assert run.update(t, LENGTHS, still) is None
        t += 0.01
    assert run.still_after_s == pytest.approx(0.41 + S.settle_s, abs=0.011)


def test_a_non_finite_rate_counts_as_moving() -> None:
    run = _run()
    for k in range(200):
        assert run.update(100.0 + 0.01 * k, LENGTHS, (0.0, math.nan, 0.0, 0.0)) is None
    assert not run.done and run.worst_mps == math.inf


def test_travel_beyond_the_limit_fails_naming_the_cable() -> None:
    run = _run()
    lengths = list(LENGTHS)
    lengths[2] -= 0.31
    why = run.update(100.1, lengths, (0.0, 0.0, -0.1, 0.0))
    assert why is not None
    assert why.startswith("cable 3 moved 0.310 m without coming still")
    assert "homing.pretension_max_travel_m 0.3 m" in why
    lengths[2] = LENGTHS[2] - 0.29  # within the limit: fine
    assert _run().update(100.1, lengths, (0.0, 0.0, -0.1, 0.0)) is None


def test_no_stillness_within_the_timeout_fails_naming_the_fastest_cable() -> None:
    run = _run()
    rates = (0.001, 0.0, -0.004, 0.003)
    t = 100.0
    why = None
    while why is None:
        why = run.update(t, LENGTHS, rates)
        t += 0.05
        assert t < 111.0
    assert t - 100.0 > S.timeout_s
    assert why.startswith("not still after 10 s (homing.pretension_timeout_s): cable 3 at 4 mm/s")
    assert not run.done
