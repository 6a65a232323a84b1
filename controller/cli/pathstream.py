"""Streaming motion to the daemon in chunks, paced by its queue: the client library's
`controller.client.stream` (one rule for every client that streams), importable from here by
the verbs' older name."""

from __future__ import annotations

from controller.client.stream import (
    LOW_WATER_S,
    MAX_POLL_S,
    MOTION_STATES,
    POLL_S,
    Pacer,
    RobotLeft,
    Send,
    StreamProgress,
    StreamRefused,
    iter_points,
    stream_points,
)

__all__ = [
    "LOW_WATER_S",
    "MAX_POLL_S",
    "MOTION_STATES",
    "POLL_S",
    "Pacer",
    "RobotLeft",
    "Send",
    "StreamProgress",
    "StreamRefused",
    "iter_points",
    "stream_points",
]
