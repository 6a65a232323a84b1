"""The `[bus]` and `[zenoh]` tables: python-can interface names and options, Zenoh endpoints
and configuration files."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

from controller.core.suggest import closest
from controller.service.config.schema import (
    _PREFIX_RE,
    _ZENOH_MODES,
    BusConfig,
    Ros2Config,
    ZenohConfig,
)
from controller.service.config.tables import _Table, _tname, _unknown

_BUS_KEYS = tuple(BusConfig.__dataclass_fields__)


def _parse_bus(top: _Table) -> BusConfig:
    b = top.sub("bus")
    b.finish(_BUS_KEYS)
    d_bus = BusConfig()
    interface = b.string("interface", d_bus.interface) or d_bus.interface
    problem = _interface_problem(interface)
    if problem is not None:
        b.fail("interface", problem)
    channel_raw = b.raw("channel") if b.has("channel") else d_bus.channel
    if isinstance(channel_raw, bool) or not isinstance(channel_raw, str | int) or channel_raw == "":
        b.fail("channel", f"must be a non-empty string or an integer, got {channel_raw!r}")
        channel_raw = d_bus.channel
    bitrate: int | None = None
    if b.has("bitrate"):
        bitrate = b.integer("bitrate", ge=10_000, le=8_000_000)
    options: dict[str, Any] = {}
    if b.has("options"):
        opts = b.raw("options")
        if not isinstance(opts, Mapping):
            b.fail("options", f"must be a table, got {_tname(opts)}")
        else:
            options = dict(opts)
    for reserved in ("interface", "channel", "bitrate"):
        if reserved in options:
            b.fail(f"options.{reserved}", f"set it as bus.{reserved}, not in options")
            del options[reserved]
    if options and problem is None:
        allowed = bus_option_names(interface)
        if allowed is not None:
            for k in options:
                if k not in allowed:
                    b.fail(
                        f"options.{k}",
                        _unknown(k, set(allowed)).replace(
                            "unknown key", f"not an option of the {interface} interface"
                        )
                        + f" (it takes: {', '.join(sorted(allowed))})",
                    )
    return BusConfig(interface, str(channel_raw), bitrate, MappingProxyType(options))


def _interface_problem(interface: str) -> str | None:
    """Why `interface` is not a python-can interface name, or None if it is one."""
    import can

    valid = sorted(can.interfaces.VALID_INTERFACES)
    if interface in valid:
        return None
    close = closest(interface, valid)
    hint = f"; did you mean {close!r}?" if close else ""
    return f"unknown python-can interface {interface!r}{hint} (known: {', '.join(valid)})"


_GENERIC_BUS_OPTIONS = frozenset(
    {"timing", "fd", "data_bitrate", "state", "receive_own_messages", "can_filters"}
)
"""Keywords python-can's `can.Bus` understands for any interface (besides bit-timing fields)."""


def bus_option_names(interface: str) -> frozenset[str] | None:
    """The keyword options python-can's bus class for `interface` names in its constructor
    (plus python-can's generic ones: bit timing, fd, data_bitrate, state, can_filters), and
    `hop_limit` for udp_multicast. None if the interface's module cannot be imported here (a
    vendor library missing): its options cannot be checked. Raises nothing."""
    import importlib
    import inspect

    import can
    import can.typechecking

    entry = can.interfaces.BACKENDS.get(interface)
    if entry is None:
        return None
    module_name, class_name = entry
    try:
        cls = getattr(importlib.import_module(module_name), class_name)
        params = list(inspect.signature(cls.__init__).parameters.values())
        params += list(inspect.signature(can.BusABC.__init__).parameters.values())
    except Exception:  # a missing vendor library, an odd plugin: cannot tell
        return None
    named = {p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    named.discard("self")
    named.discard("channel")
    named |= _GENERIC_BUS_OPTIONS
    named |= set(can.typechecking.BitTimingDict.__annotations__)
    named |= set(can.typechecking.BitTimingFdDict.__annotations__)
    if interface == "udp_multicast":
        named.add("hop_limit")
    return frozenset(named)


_PORT_PROTOCOLS = frozenset({"tcp", "udp", "tls", "quic", "ws"})


def _endpoint_problem(ep: str, *, listen: bool) -> str | None:
    """Why Zenoh endpoint `ep` is malformed (protocol/address; for tcp, udp, tls, quic and ws
    host:port with a port in 1..65535, or 0 = any free port for a listen endpoint)."""
    proto, sep, rest = ep.partition("/")
    if not sep or not proto or not rest:
        return f"endpoint {ep!r} must look like 'tcp/HOST:PORT'"
    if proto not in _PORT_PROTOCOLS:
        return None  # unixsock-stream/PATH, serial/..., vsock/...: Zenoh checks these
    address = rest.split("?", 1)[0].split("#", 1)[0]
    host, colon, port_text = address.rpartition(":")
    if not colon or not host:
        return f"endpoint {ep!r} must look like '{proto}/HOST:PORT'"
    lowest = 0 if listen else 1
    if not port_text.isdigit() or not lowest <= int(port_text) <= 65535:
        return f"endpoint {ep!r}: port must be {lowest}..65535, got {port_text!r}"
    return None


def _parse_zenoh(top: _Table, name: str) -> ZenohConfig:
    zt = top.sub("zenoh")
    zt.finish(tuple(ZenohConfig.__dataclass_fields__))
    d_z = ZenohConfig()
    prefix = zt.string("prefix", f"cablebot/{name}") or f"cablebot/{name}"
    if not _PREFIX_RE.match(prefix):
        zt.fail(
            "prefix",
            f"must be a plain key expression like 'cablebot/desk' (no wildcards), got {prefix!r}",
        )
    mode = zt.string("mode", d_z.mode) or d_z.mode
    if mode not in _ZENOH_MODES:
        zt.fail("mode", f"must be one of {', '.join(_ZENOH_MODES)}, got {mode!r}")
    listen = zt.strings("listen", d_z.listen)
    connect = zt.strings("connect", d_z.connect)
    for k, eps in (("listen", listen), ("connect", connect)):
        for ep in eps:
            problem = _endpoint_problem(ep, listen=k == "listen")
            if problem is not None:
                zt.fail(k, problem)
    scouting = zt.boolean("multicast_scouting", d_z.multicast_scouting)
    zcfg = zt.string("config_file", None)
    if zcfg is not None:
        zcfg = os.path.expanduser(zcfg)
        if not Path(zcfg).is_file():
            zt.fail("config_file", f"no such file: {zcfg}")
        else:
            problem = _zenoh_file_problem(zcfg)
            if problem is not None:
                zt.fail("config_file", problem)
    return ZenohConfig(prefix, mode, listen, connect, scouting, zcfg)


def _zenoh_file_problem(path: str) -> str | None:
    """Why Zenoh cannot use the JSON5 configuration at `path` (unloadable, or a malformed
    listen/connect endpoint that it sets), or None if it can."""
    try:
        import zenoh
    except ImportError:  # pragma: no cover - zenoh is a dependency
        return None
    try:
        conf = zenoh.Config.from_file(path)
        defaults = zenoh.Config()
        problems = []
        for key in ("listen/endpoints", "connect/endpoints"):
            text = conf.get_json(key)
            if text == defaults.get_json(key):
                continue
            value = json.loads(text)
            groups = value.values() if isinstance(value, dict) else [value]
            for eps in groups:
                for ep in eps if isinstance(eps, list) else [eps]:
                    problem = _endpoint_problem(str(ep), listen=key.startswith("listen"))
                    if problem is not None:
                        problems.append(f"{key.split('/')[0]}: {problem}")
    except Exception as exc:  # zenoh.ZError, OSError, UnicodeDecodeError...
        return f"not a valid Zenoh configuration: {type(exc).__name__}: {exc}"
    return "; ".join(problems) if problems else None


_ROS2_NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")


def _parse_ros2(top: _Table) -> Ros2Config:
    rt = top.sub("ros2")
    rt.finish(tuple(Ros2Config.__dataclass_fields__))
    d = Ros2Config()
    enabled = rt.boolean("enabled", d.enabled)
    domain_id = rt.integer("domain_id", d.domain_id, ge=0, le=232)
    ns = rt.string("namespace", d.namespace) or d.namespace
    parts = ns.strip("/").split("/") if ns != "/" else []
    if not ns.startswith("/") or not all(_ROS2_NAME_RE.match(x) for x in parts):
        rt.fail("namespace", f"must be an absolute ROS namespace like '/cablebot', got {ns!r}")
    node_name = rt.string("node_name", d.node_name) or d.node_name
    if not _ROS2_NAME_RE.match(node_name):
        rt.fail("node_name", f"must be a ROS name (letters, digits, _), got {node_name!r}")
    frame_id = rt.string("frame_id", d.frame_id) or d.frame_id
    if not frame_id.isprintable() or len(frame_id) > 256:
        rt.fail("frame_id", f"must be printable and at most 256 characters, got {frame_id!r}")
    return Ros2Config(enabled, domain_id, ns.rstrip("/") or "/", node_name, frame_id)
