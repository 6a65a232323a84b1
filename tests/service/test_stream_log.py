"""Refused and discarded streamed set-points are logged off the loop thread (`StreamLog`), at
most one line per kind a second, with how many there were, and named in `status`'s text."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import pytest

from controller.cli.formats import format_status, setpoints_line
from controller.service.stream_log import StreamLog


@dataclass
class _Ctl:
    stream_refused: int = 0
    stream_last_refusal: str | None = None
    stream_discarded: int = 0
    stream_last_discard: str | None = None


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    out = [r.getMessage() for r in caplog.records if r.name == "cablebot.stream"]
    caplog.clear()
    return out


def test_each_refusal_is_logged_with_its_reason_at_most_once_a_second(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, logger="cablebot.stream")
    ctl, clock = _Ctl(), _Clock()
    watch = StreamLog(ctl, clock=clock)
    watch.step()
    assert _lines(caplog) == []  # nothing new: nothing said
    ctl.stream_last_refusal, ctl.stream_refused = "z=90 m above the anchor plane", 1
    watch.step()
    assert _lines(caplog) == ["streamed set-point refused: z=90 m above the anchor plane"]
    for i in range(3):  # a flood within the second: counted, said once the second is up
        ctl.stream_last_refusal, ctl.stream_refused = f"x={i} m outside", ctl.stream_refused + 1
        clock.t += 0.1
        watch.step()
    assert _lines(caplog) == []
    clock.t += 0.8
    watch.step()
    assert _lines(caplog) == [
        "streamed set-point refused: x=2 m outside (the latest of 3 since the last line)"
    ]
    ctl.stream_last_discard = "not allowed in DISARMED: the motors are disarmed: arm first"
    ctl.stream_discarded = 2
    watch.step()  # the discards have a second of their own
    assert _lines(caplog) == [
        "streamed set-point discarded: not allowed in DISARMED: the motors are disarmed: arm "
        "first (the latest of 2 since the last line)"
    ]


def test_counts_from_before_the_watch_started_are_not_logged(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, logger="cablebot.stream")
    watch = StreamLog(_Ctl(5, "old", 7, "older"), clock=_Clock())
    watch.step()
    assert _lines(caplog) == []


def test_status_text_shows_refusals_as_refusals() -> None:
    st = {
        "state": "HOLDING",
        "zenoh": {"setpoints": {"ok": 3, "bad": 1}, "commands": {"ok": 0}},
        "stream": {
            "refused": 1,
            "last_refusal": "z=90 m above the anchor plane minus margin (6.62 m)",
            "discarded": 0,
            "last_discard": None,
        },
    }
    assert (
        "set-points received 4, malformed 1, refused 1 (last: z=90 m above the anchor plane "
        "minus margin (6.62 m)), discarded 0"
    ) in format_status(st).splitlines()
    assert setpoints_line(None, {"refused": 0, "discarded": 2, "last_discard": "disarmed"}) == (
        "set-points refused 0, discarded 2 (last: disarmed)"
    )
