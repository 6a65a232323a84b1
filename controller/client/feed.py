"""Samples of a published key as they arrive (the pose, the simulator's truth): the latest one,
and a queue for each follower (a wait, an iterator, a callback).

Zenoh calls `Feed.on_sample` on its own thread for every sample: it is decoded once (a sample
that is not valid JSON of the expected kind is counted in `malformed` and dropped), kept as the
latest, and handed to every follower. A follower's queue is a `queue.SimpleQueue`, whose wait
Ctrl-C interrupts cleanly (`queue.Queue`'s condition could turn a KeyboardInterrupt into
"RuntimeError: release unlocked lock"), bounded: past `limit` samples the oldest is dropped
and counted, so a follower nobody reads never grows without end.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from typing import Any, Generic, TypeVar

T = TypeVar("T")

FOLLOWER_LIMIT = 10_000
"""The most samples a follower keeps unread (at 100 samples a second, 100 s of them)."""


class Follower(Generic[T]):
    """The samples of a `Feed` from the moment it was made: `get` them in order, or have each
    handed to `sink` on Zenoh's thread instead (a callback must return quickly). `dropped`
    counts samples dropped because more than `limit` were unread. `close()` ends it."""

    def __init__(
        self,
        feed: Feed[T],
        limit: int = FOLLOWER_LIMIT,
        sink: Callable[[T], None] | None = None,
    ) -> None:
        self._feed = feed
        self._queue: queue.SimpleQueue[T] = queue.SimpleQueue()
        self.limit = limit
        self.sink = sink
        self.dropped = 0

    def put(self, item: T) -> None:
        """Take one sample (Zenoh's thread). Never raises: a sink's error is counted as a
        dropped sample."""
        self.seen(item)
        if self.sink is not None:
            try:
                self.sink(item)
            except Exception:
                self.dropped += 1
            return
        if self._queue.qsize() >= self.limit:
            try:
                self._queue.get_nowait()
                self.dropped += 1
            except queue.Empty:
                pass
        self._queue.put(item)

    def seen(self, item: T) -> None:
        """Called with every sample as it arrives, before it is queued (for subclasses that
        note something about the stream as it passes)."""

    def get(self, timeout: float) -> T | None:
        """The next sample, waiting at most `timeout` seconds; None when none came."""
        try:
            return self._queue.get(timeout=max(0.0, timeout))
        except queue.Empty:
            return None

    def get_nowait(self) -> T | None:
        """The next sample if one is queued, else None."""
        try:
            return self._queue.get_nowait()
        except queue.Empty:
            return None

    def drain(self) -> None:
        """Drop every sample queued so far."""
        while self.get_nowait() is not None:
            pass

    def close(self) -> None:
        """Stop following (idempotent)."""
        self._feed.remove(self)

    def __enter__(self) -> Follower[T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Feed(Generic[T]):
    """The decoded samples of one key: `parse(bytes, received_s)` decodes one (raising
    ValueError for a malformed one). Thread-safe."""

    def __init__(self, parse: Callable[[bytes, float], T]) -> None:
        self._parse = parse
        self._lock = threading.Lock()
        self._latest: T | None = None
        self._followers: tuple[Follower[T], ...] = ()
        self.received = 0
        self.malformed = 0

    def on_sample(self, sample: Any) -> None:
        """Zenoh's subscriber callback: decode, keep, hand out. Never raises."""
        try:
            data = sample.payload.to_bytes()
        except Exception:
            self.malformed += 1
            return
        self.on_bytes(data)

    def on_bytes(self, data: bytes) -> None:
        """Take one sample's bytes (see `on_sample`). Never raises."""
        try:
            item = self._parse(data, time.monotonic())
        except (ValueError, TypeError):
            with self._lock:
                self.malformed += 1
            return
        with self._lock:
            self._latest = item
            self.received += 1
            followers = self._followers
        for f in followers:
            f.put(item)

    @property
    def latest(self) -> T | None:
        """The newest sample received, or None before the first."""
        with self._lock:
            return self._latest

    def add(self, follower: Follower[T]) -> Follower[T]:
        """Start handing samples to `follower`; returns it."""
        with self._lock:
            self._followers = (*self._followers, follower)
        return follower

    def follow(self, limit: int = FOLLOWER_LIMIT) -> Follower[T]:
        """A new follower of the samples from now on."""
        return self.add(Follower(self, limit))

    def remove(self, follower: Follower[T]) -> None:
        """Stop handing samples to `follower` (idempotent)."""
        with self._lock:
            self._followers = tuple(f for f in self._followers if f is not follower)
