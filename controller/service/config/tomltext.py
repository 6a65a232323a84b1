"""TOML text of a robot mapping: how a robot built from a mapping (the built-in robot, a robot
made in code) is described as the text a robot file would hold (`RobotConfig.text`, served by
the daemon on `<prefix>/robot`)."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping, Sequence
from typing import Any

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _key(name: str) -> str:
    return name if _BARE_KEY.fullmatch(name) else json.dumps(name)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a JSON string is a TOML basic string
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{_key(str(k))} = {_value(x)}" for k, x in v.items()) + "}"
    if isinstance(v, Sequence):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} {v!r} as TOML")


def _is_table_array(v: Any) -> bool:
    return (
        isinstance(v, Sequence)
        and not isinstance(v, str)
        and len(v) > 0
        and all(isinstance(x, Mapping) for x in v)
    )


def _table(data: Mapping[str, Any], path: str, out: list[str]) -> None:
    """Write the scalar keys of `data`, then its sub-tables and arrays of tables."""
    subs: list[tuple[str, Any]] = []
    for k, v in data.items():
        if v is None:
            continue  # TOML has no null: an unset key is left out
        if isinstance(v, Mapping) or _is_table_array(v):
            subs.append((k, v))
        else:
            out.append(f"{_key(str(k))} = {_value(v)}")
    for k, v in subs:
        name = f"{path}.{_key(str(k))}" if path else _key(str(k))
        if isinstance(v, Mapping):
            out.append(f"\n[{name}]")
            _table(v, name, out)
        else:
            for item in v:
                out.append(f"\n[[{name}]]")
                _table(item, name, out)


def to_toml(data: Mapping[str, Any]) -> str:
    """The TOML text of a robot mapping (`tomllib.loads` reads it back to the same mapping,
    keys set to None left out). Raises TypeError for a value TOML cannot hold."""
    out: list[str] = []
    _table(data, "", out)
    return "\n".join(out).lstrip("\n") + "\n"
