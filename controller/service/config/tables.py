"""Validation primitives: one TOML table read with typed getters, every problem collected.

`_Table` reads one table's keys (numbers, integers, booleans, strings, string lists, [x, y, z]
points, sub-tables) and records each problem in a shared `_Errors`, returning a stand-in so that
validation goes on and every problem of a file is reported at once; `finish()` reports unknown
keys with a did-you-mean hint.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, overload

from controller.core.suggest import closest
from controller.service.config.schema import _MAX_ABS, ConfigError, Vec3

_UNIT_WORDS = {
    "_kg_per_m": "kilograms per metre",
    "_kg": "kilograms",
    "_nm": "newton-metres",
    "_n": "newtons",
    "_per_rev": "units per motor turn",
    "_per_rps": "units per motor turn per second",
    "_mps2": "metres per second squared",
    "_rps2": "motor turns per second squared",
    "_m_per_rev2": "metres per turn per turn",
    "_mps": "metres per second",
    "_rps": "motor turns per second",
    "_hz": "hertz",
    "_rev": "motor turns",
    "_m": "metres",
    "_s": "seconds",
}


def _unit_of(key: str) -> str | None:
    for suffix, words in _UNIT_WORDS.items():
        if key.endswith(suffix):
            return words
    return None


class _Errors:
    """Every problem found in one configuration, in the order found."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.items: list[ConfigError] = []

    def add(self, key: str, problem: str) -> None:
        self.items.append(ConfigError(self.source, key, problem))

    def mark(self) -> int:
        return len(self.items)

    def clean_since(self, mark: int) -> bool:
        """True if no problem was found since `mark()` returned `mark`."""
        return len(self.items) == mark

    def check(self, key: str, fn: Callable[[], None]) -> None:
        """Run a cross-check that raises ConfigError; record its problems and go on. A value
        that makes the arithmetic fail is reported against `key` too."""
        try:
            fn()
        except ConfigError as exc:
            self.items.extend(exc.errors)
        except (ArithmeticError, ValueError) as exc:
            self.add(key, f"values out of range for the checks ({type(exc).__name__}: {exc})")

    def raise_if_any(self) -> None:
        """Raise one ConfigError listing every problem found (nothing if none)."""
        if self.items:
            raise ConfigError.collected(self.source, self.items)


class _Table:
    """One TOML table being validated: typed getters that record which keys were used.

    A getter that finds a problem records it in `errs` and returns a stand-in (the default, or
    NaN / None), so that validation goes on and every problem is reported at once; checks that
    combine values run only when their inputs were clean.
    """

    def __init__(self, data: Any, path: str, errs: _Errors) -> None:
        self.path = path
        self.errs = errs
        self.source = errs.source
        self.used: set[str] = set()
        if isinstance(data, Mapping):
            self.data: Mapping[str, Any] = data
        else:
            errs.add(path, f"must be a table, got {_tname(data)}")
            self.data = {}

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def error(self, name: str, problem: str) -> ConfigError:
        return ConfigError(self.source, self.key(name), problem)

    def fail(self, name: str, problem: str) -> None:
        """Record a problem with key `name` of this table."""
        self.errs.add(self.key(name), problem)

    def fail_here(self, problem: str) -> None:
        """Record a problem with this table as a whole."""
        self.errs.add(self.path, problem)

    def has(self, name: str) -> bool:
        return name in self.data

    def raw(self, name: str) -> Any:
        self.used.add(name)
        return self.data[name]

    def number(
        self,
        name: str,
        default: float | None = None,
        *,
        gt: float | None = None,
        ge: float | None = None,
        le: float | None = None,
        required: bool = False,
    ) -> float:
        fallback = math.nan if default is None else default
        if name not in self.data:
            if required or default is None:
                self.fail(name, "missing (required)")
            return fallback
        v = self.raw(name)
        if isinstance(v, bool) or not isinstance(v, int | float):
            unit = _unit_of(name)
            hint = f" in {unit} (the unit is in the key name)" if unit else ""
            self.fail(name, f"must be a number{hint}, got {v!r}")
            return fallback
        try:
            f = float(v)
        except OverflowError:  # an integer beyond float range
            f = math.inf
        problem = None
        if not math.isfinite(f):
            problem = f"must be finite, got {v!r}"
        elif abs(f) > _MAX_ABS:
            problem = f"must be within ±{_MAX_ABS:g}, got {v!r}"
        elif gt is not None and not f > gt:
            problem = f"must be > {gt:g}, got {v!r}"
        elif ge is not None and not f >= ge:
            problem = f"must be >= {ge:g}, got {v!r}"
        elif le is not None and not f <= le:
            problem = f"must be <= {le:g}, got {v!r}"
        if problem is not None:
            self.fail(name, problem)
            return fallback
        return f

    @overload
    def integer(
        self, name: str, default: int, *, ge: int | None = None, le: int | None = None
    ) -> int: ...

    @overload
    def integer(
        self, name: str, default: None = None, *, ge: int | None = None, le: int | None = None
    ) -> int | None: ...

    def integer(
        self, name: str, default: int | None = None, *, ge: int | None = None, le: int | None = None
    ) -> int | None:
        """The integer at `name`; None (after recording the problem) if it is missing without
        a default or invalid and there is no default."""
        if name not in self.data:
            if default is None:
                self.fail(name, "missing (required)")
            return default
        v = self.raw(name)
        problem = None
        if isinstance(v, bool) or not isinstance(v, int):
            problem = f"must be an integer, got {v!r}"
        elif ge is not None and v < ge:
            problem = f"must be >= {ge}, got {v}"
        elif le is not None and v > le:
            problem = f"must be <= {le}, got {v}"
        if problem is not None:
            self.fail(name, problem)
            return default
        return int(v)

    def boolean(self, name: str, default: bool) -> bool:
        if name not in self.data:
            return default
        v = self.raw(name)
        if not isinstance(v, bool):
            self.fail(name, f"must be true or false, got {v!r}")
            return default
        return v

    def string(self, name: str, default: str | None) -> str | None:
        if name not in self.data:
            return default
        v = self.raw(name)
        if not isinstance(v, str) or not v:
            self.fail(name, f"must be a non-empty string, got {v!r}")
            return default
        return v

    def strings(self, name: str, default: tuple[str, ...]) -> tuple[str, ...]:
        if name not in self.data:
            return default
        v = self.raw(name)
        if not isinstance(v, list) or not all(isinstance(s, str) and s for s in v):
            self.fail(name, f"must be a list of non-empty strings, got {v!r}")
            return default
        return tuple(v)

    def vec3(self, name: str, *, required: bool = True) -> Vec3 | None:
        """[x, y, z] in metres at `name`; None if absent (recorded when `required`) or bad."""
        if name not in self.data:
            if required:
                self.fail(name, "missing (required)")
            return None
        v = self.raw(name)
        if (
            not isinstance(v, list)
            or len(v) != 3
            or not all(isinstance(x, int | float) and not isinstance(x, bool) for x in v)
        ):
            self.fail(name, f"must be [x, y, z] in metres (3 numbers), got {v!r}")
            return None
        try:
            x, y, z = (float(c) for c in v)
        except OverflowError:
            x = y = z = math.inf
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            self.fail(name, f"must be finite, got {v!r}")
            return None
        if max(abs(x), abs(y), abs(z)) > _MAX_ABS:
            self.fail(name, f"coordinates must be within ±{_MAX_ABS:g} m, got {v!r}")
            return None
        return (x, y, z)

    def sub(self, name: str) -> _Table:
        if name not in self.data:
            return _Table({}, self.key(name), self.errs)
        return _Table(self.raw(name), self.key(name), self.errs)

    def finish(self, allowed: tuple[str, ...]) -> None:
        """Record every key not in `allowed` (unknown key, with a did-you-mean hint)."""
        known = set(allowed)
        for k in self.data:
            if k not in known:
                self.fail(k, _unknown(k, known))


def _unknown(key: str, known: set[str]) -> str:
    close = closest(key, known)
    hint = f"; did you mean {close!r}?" if close else ""
    if not close:
        stem = key.rsplit("_", 1)[0]
        same_stem = sorted(k for k in known if k.rsplit("_", 1)[0] == stem)
        if same_stem:
            hint = f"; units are part of key names: did you mean {same_stem[0]!r}?"
    return f"unknown key{hint}"


def _tname(v: Any) -> str:
    return type(v).__name__
