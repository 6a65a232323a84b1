"""`cablebot record FILE.mcap`: every key under the robot's prefix into one MCAP file.

The recorder is a Zenoh client like any other: it subscribes to `<prefix>/**` (the pose, the
state changes, streamed set-points, anything else put under the prefix), queries
`<prefix>/status` at `--status-hz`, and follows the daemon's liveliness token
`<prefix>/alive`. The daemon's loop does not notice it.

The file (the format `replay` and `plot` read):

- one MCAP channel per Zenoh key, its topic the key itself (`cablebot/default/pose`), message
  encoding `json`, a JSON Schema per kind of key (`KEY_SCHEMAS`; `cablebot.Json` for keys this
  version does not know). Messages are the payloads exactly as received. `log_time` is when the
  recorder received the sample (wall clock, ns), `publish_time` the payload's `stamp_ns` when
  it has one, `sequence` the pose's `seq` (modulo 2^32).
- `<prefix>/status`: the status replies; `<prefix>/alive`: `{"alive": bool}` on every change
  of the daemon's liveliness token.
- metadata `cablebot.recording`: prefix, endpoint, status rate, start time.
- metadata `cablebot.config`: the configuration the daemon runs with: the `config` of its
  status (`source` "status"), written when first seen and again whenever it changes; with
  `--config FILE` also that file's summary (`source` "file", written at the start) and the file
  itself as an attachment. Readers prefer the daemon's own (`Recording.config_summary`).

Long runs: the chunks are small (`CHUNK_SIZE`) and the writer flushes at least every
`--flush-s` seconds, so a recorder killed with SIGKILL leaves a file readable up to its last
flushed chunk (`Recording` reads such a file and says it was cut short). Memory stays bounded:
samples wait in a bounded queue (overflow is counted, never blocks Zenoh), and what grows with
the length of the run is the MCAP summary's chunk and message index (what lets Foxglove seek in
a long file), measured at about 0.7 kB per flush: 2.5 MB per hour at one flush a second.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Generator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import IO, Any

from controller.cli.zenoh_threads import start_zenoh_thread

CHUNK_SIZE = 256 * 1024
"""Close an MCAP chunk when it holds this many (uncompressed) bytes."""
DEFAULT_FLUSH_S = 1.0
DEFAULT_STATUS_HZ = 4.0
QUEUE_SIZE = 65536
"""Samples waiting for the writer; beyond it new samples are dropped and counted."""
META_RECORDING = "cablebot.recording"
META_CONFIG = "cablebot.config"

_NUM_OR_NULL: dict[str, Any] = {"type": ["number", "null"]}
_XYZ_OR_NULL: dict[str, Any] = {
    "type": ["array", "null"],
    "items": {"type": "number"},
    "minItems": 3,
    "maxItems": 3,
}

KEY_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    "pose": (
        "cablebot.Pose",
        {
            "title": "cablebot pose sample",
            "type": "object",
            "properties": {
                "seq": {"type": "integer"},
                "stamp_ns": {"type": "integer"},
                "position_m": _XYZ_OR_NULL,
                "cable_lengths_m": {"type": "array", "items": _NUM_OR_NULL},
                "residual_m": _NUM_OR_NULL,
                "valid": {"type": "boolean"},
                "state": {"type": "string"},
            },
            "required": [
                "seq",
                "stamp_ns",
                "position_m",
                "cable_lengths_m",
                "residual_m",
                "valid",
                "state",
            ],
        },
    ),
    "state": (
        "cablebot.State",
        {
            "title": "cablebot state change",
            "type": "object",
            "properties": {
                "state": {"type": "string"},
                "reason": {"type": ["string", "null"]},
                "stamp_ns": {"type": "integer"},
            },
            "required": ["state", "reason", "stamp_ns"],
        },
    ),
    "status": (
        "cablebot.Status",
        {
            "title": "cablebot status reply",
            "type": "object",
            "properties": {
                "state": {"type": "string"},
                "reason": {"type": ["string", "null"]},
                "pose": {"type": "object"},
                "setpoint_m": _XYZ_OR_NULL,
                "axes": {"type": "array"},
                "loop": {"type": "object"},
                "bus": {"type": "object"},
                "config": {"type": "object"},
                "zenoh": {"type": "object"},
            },
        },
    ),
    "setpoint": (
        "cablebot.Setpoint",
        {
            "title": "cablebot streamed set-point",
            "type": "object",
            "properties": {"position_m": _XYZ_OR_NULL},
        },
    ),
    "alive": (
        "cablebot.Alive",
        {
            "title": "cablebot daemon liveliness",
            "type": "object",
            "properties": {"alive": {"type": "boolean"}},
            "required": ["alive"],
        },
    ),
}
"""JSON Schema (name, schema) per key suffix under the prefix."""
GENERIC_SCHEMA: tuple[str, dict[str, Any]] = ("cablebot.Json", {"title": "JSON value"})


def schema_for_key(key: str, prefix: str) -> tuple[str, dict[str, Any]]:
    """The (name, JSON Schema) recorded for Zenoh key `key` under `prefix`."""
    suffix = key[len(prefix) + 1 :] if key.startswith(prefix + "/") else key
    return KEY_SCHEMAS.get(suffix, GENERIC_SCHEMA)


# --------------------------------------------------------------------------------------------
# Writing


class McapRecorder:
    """Writes cablebot samples into an MCAP stream (one thread; not thread-safe).

    `add(key, data, recv_ns)` writes one sample; `flush_if_due()` closes the chunk when
    `flush_s` passed since the last flush; `close()` writes the summary. Raises OSError when the
    stream cannot be written.
    """

    def __init__(
        self,
        stream: IO[bytes],
        prefix: str,
        *,
        flush_s: float = DEFAULT_FLUSH_S,
        chunk_size: int = CHUNK_SIZE,
        clock: Any = time.monotonic,
    ) -> None:
        from mcap.writer import CompressionType, Writer

        self.prefix = prefix.rstrip("/")
        self._stream = stream
        self._writer = Writer(stream, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="cablebot record")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._clock = clock
        self._flush_s = flush_s
        self._last_flush = clock()
        self._config_json: tuple[str, str] | None = None
        self.counts: dict[str, int] = {}
        self.not_json = 0
        self.flushes = 0

    def _channel(self, key: str) -> int:
        cid = self._channels.get(key)
        if cid is None:
            name, schema = schema_for_key(key, self.prefix)
            sid = self._schemas.get(name)
            if sid is None:
                sid = self._writer.register_schema(
                    name=name, encoding="jsonschema", data=json.dumps(schema).encode()
                )
                self._schemas[name] = sid
            cid = self._writer.register_channel(topic=key, message_encoding="json", schema_id=sid)
            self._channels[key] = cid
        return cid

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write an MCAP metadata record."""
        self._writer.add_metadata(name, dict(data))

    def add_attachment(self, name: str, media_type: str, data: bytes, time_ns: int) -> None:
        """Write an MCAP attachment (e.g. the robot's TOML file)."""
        self._writer.add_attachment(
            create_time=time_ns, log_time=time_ns, name=name, media_type=media_type, data=data
        )

    def add_config(self, summary: Mapping[str, Any], source: str, **extra: str) -> None:
        """Store a configuration summary (`cablebot.config`) unless the last one stored came
        from the same source with the same content."""
        text = json.dumps(summary, sort_keys=True, separators=(",", ":"))
        if (source, text) == self._config_json:
            return
        self._config_json = (source, text)
        self.add_metadata(META_CONFIG, {"source": source, "summary": text, **extra})

    def add(self, key: str, data: bytes, recv_ns: int) -> bool:
        """Write one sample received on `key`; False (counted) if it is not a JSON payload."""
        try:
            value = json.loads(data)
        except ValueError:
            self.not_json += 1
            return False
        stamp_ns = recv_ns
        seq = 0
        if isinstance(value, dict):
            s = value.get("stamp_ns")
            if isinstance(s, int) and s > 0:
                stamp_ns = s
            q = value.get("seq")
            if isinstance(q, int) and q >= 0:
                seq = q & 0xFFFFFFFF
            cfg = value.get("config")
            if key == f"{self.prefix}/status" and isinstance(cfg, dict) and cfg.get("reels"):
                self.add_config(cfg, "status")
        self._writer.add_message(
            channel_id=self._channel(key),
            log_time=recv_ns,
            data=data,
            publish_time=stamp_ns,
            sequence=seq,
        )
        self.counts[key] = self.counts.get(key, 0) + 1
        return True

    def flush_if_due(self) -> None:
        """Close the open chunk and flush the stream if `flush_s` passed since the last flush."""
        now = self._clock()
        if now - self._last_flush >= self._flush_s:
            self.flush()

    def flush(self) -> None:
        """Close the open chunk and flush the stream now."""
        self._writer.flush()  # type: ignore[no-untyped-call]
        self._last_flush = self._clock()
        self.flushes += 1

    def close(self) -> None:
        """Write the summary and footer (the stream stays open)."""
        self._writer.finish()  # type: ignore[no-untyped-call]


# --------------------------------------------------------------------------------------------
# Reading


@dataclass(frozen=True, slots=True)
class RecordedMessage:
    """One recorded sample: its key (`topic`), times (ns), sequence and the payload bytes."""

    topic: str
    log_time_ns: int
    publish_time_ns: int
    sequence: int
    data: bytes


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The bytes every MCAP file starts (and ends) with."""


def _unreadable_reason(path: Path, exc: BaseException) -> str:
    """Why a file that did not yield its first MCAP record is not a recording, for people."""
    import struct

    from mcap.exceptions import EndOfFile

    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError:
        return str(exc) or type(exc).__name__
    if size == 0:
        return "the file is empty (0 bytes)"
    if head != MCAP_MAGIC[: len(head)]:
        return "not an MCAP file (it does not start with MCAP's magic bytes)"
    if len(head) < len(MCAP_MAGIC) or isinstance(exc, EndOfFile | struct.error):
        return f"the file is cut off after {size} bytes, before its first record"
    return str(exc) or f"{type(exc).__name__} reading its first record"


@dataclass
class Recording:
    """A cablebot MCAP file, read front to back (works on a file cut short by a kill).

    Iterate `messages()` (it can be called again; each call reads the file anew). While it
    reads, `metadata` and `attachments` fill in; `complete` says whether the file ended with
    its footer, `error` why reading stopped early, if it did.
    """

    path: Path
    metadata: list[tuple[str, dict[str, str]]] = field(default_factory=list)
    attachments: list[tuple[str, str, bytes]] = field(default_factory=list)
    complete: bool = False
    error: str | None = None

    def messages(self) -> Generator[RecordedMessage, None, None]:
        """Every message in file order. Raises OSError if the file cannot be opened,
        mcap.exceptions.McapError if it is not an MCAP file; a damaged or cut tail ends the
        iteration (and `error` says why)."""
        from mcap.exceptions import McapError
        from mcap.records import Attachment, Channel, Footer, Message, Metadata
        from mcap.stream_reader import StreamReader

        self.metadata.clear()
        self.attachments.clear()
        self.complete = False
        self.error = None
        topics: dict[int, str] = {}
        started = False
        with open(self.path, "rb") as f:
            records = StreamReader(f).records
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    break
                except Exception as exc:
                    if not started:  # not an MCAP file (bad magic) or an empty one
                        reason = _unreadable_reason(self.path, exc)
                        raise McapError(f"not a cablebot recording: {reason}") from exc
                    self.error = f"{type(exc).__name__}: {exc}"  # a cut or damaged tail
                    break
                started = True
                if isinstance(record, Message):
                    topic = topics.get(record.channel_id)
                    if topic is not None:
                        yield RecordedMessage(
                            topic,
                            record.log_time,
                            record.publish_time,
                            record.sequence,
                            record.data,
                        )
                elif isinstance(record, Channel):
                    topics[record.id] = record.topic
                elif isinstance(record, Metadata):
                    self.metadata.append((record.name, dict(record.metadata)))
                elif isinstance(record, Attachment):
                    self.attachments.append((record.name, record.media_type, record.data))
                elif isinstance(record, Footer):
                    self.complete = True

    def config_summary(self) -> dict[str, Any] | None:
        """The configuration stored in the file: the daemon's own (last one seen) if any, else
        the one from `--config`; None without either. Call after reading `messages()`."""
        best: dict[str, Any] | None = None
        for name, data in self.metadata:
            if name != META_CONFIG:
                continue
            try:
                summary = json.loads(data.get("summary", ""))
            except ValueError:
                continue
            if not isinstance(summary, dict):
                continue
            if data.get("source") == "status" or best is None:
                best = summary
        return best

    def recorded_prefix(self) -> str | None:
        """The key prefix the file was recorded under (None if the file does not say)."""
        for name, data in self.metadata:
            if name == META_RECORDING and "prefix" in data:
                return data["prefix"]
        return None


# --------------------------------------------------------------------------------------------
# The verb


def positive_number(text: str) -> float:
    """argparse type: a finite number > 0 (rates, durations, speed factors)."""
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def cmd_record(args: argparse.Namespace) -> int:
    """Entry point of `cablebot record`: 0 when the file was written, 1 bad input (or FILE
    exists without `--force`), 2 a bad `--connect`, 3 no daemon alive on `--prefix`."""
    from controller.cli.client import EXIT_ABSENT, EXIT_OK, EXIT_REFUSED, EXIT_USAGE
    from controller.cli.daemon_robot import check_config_with_daemon
    from controller.cli.session import (
        DaemonAbsent,
        InputError,
        Refused,
        UsageError,
        absent_message,
        live_prefixes,
        normalize_endpoint,
        open_session,
    )

    try:
        args.connect = normalize_endpoint(args.connect)
    except UsageError as exc:
        print(f"cablebot record: {exc}", file=sys.stderr)
        return EXIT_USAGE

    if os.path.exists(args.file) and not args.force:
        print(f"cablebot record: {args.file} exists; --force to overwrite it", file=sys.stderr)
        return EXIT_REFUSED
    prefix = args.prefix.rstrip("/")
    config_summary: dict[str, Any] | None = None
    config_text: bytes | None = None
    if args.config is not None:
        from controller.service.config import ConfigError, load_config

        try:
            config_summary = load_config(args.config).summary()
            config_text = Path(args.config).read_bytes()
        except (ConfigError, OSError) as exc:
            print(f"cablebot record: configuration: {exc}", file=sys.stderr)
            return EXIT_REFUSED
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    rec: McapRecorder | None = None
    try:
        with open_session(args.connect, config_file=args.zenoh_config) as session:
            live = live_prefixes(session)
            if prefix not in live:
                absent = DaemonAbsent(f"no daemon alive on {prefix}")
                absent.live = tuple(live)
                raise absent
            try:  # the file attached must describe the robot recorded
                cfg_path = None if args.config is None else str(args.config)
                check_config_with_daemon(session, prefix, args.timeout, cfg_path)
            except (InputError, Refused) as exc:
                print(f"cablebot record: {exc}", file=sys.stderr)
                return EXIT_REFUSED
            try:
                out = open(args.file, "wb")  # noqa: SIM115 (closed in the finally below)
            except OSError as exc:
                print(f"cablebot record: cannot write {args.file}: {exc}", file=sys.stderr)
                return EXIT_REFUSED
            try:
                rec = McapRecorder(out, prefix, flush_s=args.flush_s)
                rec.add_metadata(
                    META_RECORDING,
                    {
                        "prefix": prefix,
                        "connect": args.connect,
                        "status_hz": repr(args.status_hz),
                        "started_ns": str(time.time_ns()),
                    },
                )
                if config_summary is not None and config_text is not None:
                    rec.add_config(config_summary, "file", path=str(args.config))
                    rec.add_attachment(
                        Path(args.config).name, "application/toml", config_text, time.time_ns()
                    )
                _record(session, rec, prefix, args, stop)
            finally:
                try:
                    if rec is not None:
                        rec.close()
                finally:
                    out.close()
    except DaemonAbsent as exc:
        print(f"cablebot record: {absent_message(args, exc)}", file=sys.stderr)
        return EXIT_ABSENT
    except UsageError as exc:  # a --zenoh-config file Zenoh rejects
        print(f"cablebot record: {exc}", file=sys.stderr)
        return EXIT_USAGE
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
    assert rec is not None
    counts = ", ".join(f"{k.rsplit('/', 1)[-1]} {v}" for k, v in sorted(rec.counts.items()))
    print(f"wrote {args.file}: {counts or 'no messages'}; {rec.flushes} flushes", flush=True)
    return EXIT_OK


def _record(
    session: Any, rec: McapRecorder, prefix: str, args: argparse.Namespace, stop: threading.Event
) -> None:
    """Subscribe, poll the status and write until `stop` or the duration is over."""
    samples: queue.Queue[tuple[str, bytes, int]] = queue.Queue(maxsize=QUEUE_SIZE)
    dropped = [0]

    def push(key: str, data: bytes) -> None:
        try:
            samples.put_nowait((key, data, time.time_ns()))
        except queue.Full:
            dropped[0] += 1

    def on_sample(sample: Any) -> None:
        push(str(sample.key_expr), sample.payload.to_bytes())

    def on_alive(sample: Any) -> None:
        import zenoh

        alive = sample.kind == zenoh.SampleKind.PUT
        push(f"{prefix}/alive", b'{"alive":true}' if alive else b'{"alive":false}')

    def on_status(reply: Any) -> None:
        if reply.ok is not None:
            push(f"{prefix}/status", reply.ok.payload.to_bytes())

    def poll_status() -> None:
        # The queries go out at --status-hz without waiting for the answers (a daemon slow to
        # answer on a busy host does not slow the sampling); each answer is recorded on arrival.
        period_s = 1.0 / args.status_hz
        next_t = time.monotonic()
        while not stop.is_set():
            try:
                session.get(f"{prefix}/status", on_status, timeout=args.timeout)
            except Exception as exc:  # a closing session; the loop ends with `stop`
                if not stop.is_set():
                    print(f"cablebot record: status query failed: {exc}", file=sys.stderr)
            next_t = max(next_t + period_s, time.monotonic())
            stop.wait(max(0.0, next_t - time.monotonic()))

    subs = [
        session.declare_subscriber(f"{prefix}/**", on_sample),
        session.liveliness().declare_subscriber(f"{prefix}/alive", on_alive, history=True),
    ]
    poller = start_zenoh_thread(poll_status, name="cablebot-record-status")
    print(f"recording {prefix}/** via {args.connect} into {args.file}", flush=True)
    deadline = math.inf if args.duration is None else time.monotonic() + args.duration
    try:
        while not stop.is_set() and time.monotonic() < deadline:
            try:
                item = samples.get(timeout=0.05)
            except queue.Empty:
                item = None
            while item is not None:
                rec.add(*item)
                try:
                    item = samples.get_nowait()
                except queue.Empty:
                    item = None
            rec.flush_if_due()
    finally:
        stop.set()
        for s in subs:
            s.undeclare()
        poller.join(timeout=args.timeout + 1.0)
        while True:  # what arrived before the subscribers went
            try:
                rec.add(*samples.get_nowait())
            except queue.Empty:
                break
    if dropped[0] or rec.not_json:
        print(
            f"cablebot record: {dropped[0]} samples dropped (writer too slow),"
            f" {rec.not_json} not JSON (skipped)",
            file=sys.stderr,
        )


def register(sub: argparse._SubParsersAction[Any]) -> None:
    """Register `cablebot record`."""
    from controller.cli.session import add_connection_arguments

    p = sub.add_parser(
        "record",
        help="record every key of the robot into an MCAP file",
        description=(
            "Subscribe to every key under the robot's prefix and write it into one MCAP file "
            "(a channel per key, JSON with a JSON Schema), with the status sampled at "
            "--status-hz and the daemon's configuration stored as metadata. Stops after "
            "--duration or on Ctrl-C / SIGTERM; a killed recorder leaves the file readable up "
            "to its last flush."
        ),
    )
    add_connection_arguments(p)
    p.add_argument("file", metavar="FILE.mcap", help="the file to write")
    p.add_argument("--force", action="store_true", help="overwrite FILE.mcap if it exists")
    p.add_argument(
        "--duration", type=positive_number, default=None, metavar="S", help="stop after S s"
    )
    p.add_argument(
        "--status-hz",
        type=positive_number,
        default=DEFAULT_STATUS_HZ,
        metavar="HZ",
        help=f"status queries per second (default {DEFAULT_STATUS_HZ:g})",
    )
    p.add_argument(
        "--flush-s",
        type=positive_number,
        default=DEFAULT_FLUSH_S,
        metavar="S",
        help=f"close a chunk and flush at least every S s (default {DEFAULT_FLUSH_S:g})",
    )
    p.add_argument(
        "--config",
        default=None,
        metavar="FILE",
        help="also store this robot TOML, which must describe the daemon's robot (the daemon's "
        "own configuration, from its status, is stored in any case)",
    )
    p.set_defaults(func=cmd_record)
