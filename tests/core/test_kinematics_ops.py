"""Operation counts of the three-spheres algorithms, measured by running them on counting floats.

The paper (section 5) counts 25 add/subtract, 31 multiply/divide and 1 square root for its new
algorithm and 48 / 62 / 1 for the original general one.  The numbers asserted here are the ones
stated in the module docstring of controller.core.kinematics.spheres.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import pytest

from controller.core import kinematics as kin
from controller.core.kinematics import spheres

COUNT: Counter[str] = Counter()


class CF(float):
    """A float that counts the arithmetic done on it (and on results derived from it)."""

    def _op(self, kind: str, value: float) -> CF:
        COUNT[kind] += 1
        return CF(value)

    def __add__(self, o: Any) -> CF:
        return self._op("add", float(self) + float(o))

    def __radd__(self, o: Any) -> CF:
        return self._op("add", float(o) + float(self))

    def __sub__(self, o: Any) -> CF:
        return self._op("add", float(self) - float(o))

    def __rsub__(self, o: Any) -> CF:
        return self._op("add", float(o) - float(self))

    def __mul__(self, o: Any) -> CF:
        return self._op("mul", float(self) * float(o))

    def __rmul__(self, o: Any) -> CF:
        return self._op("mul", float(o) * float(self))

    def __truediv__(self, o: Any) -> CF:
        return self._op("mul", float(self) / float(o))

    def __rtruediv__(self, o: Any) -> CF:
        return self._op("mul", float(o) / float(self))

    def __pow__(self, o: Any) -> CF:  # type: ignore[override]  # not used by the algorithms; counted if it ever is
        return self._op("pow", float(self) ** float(o))

    def __neg__(self) -> CF:
        return CF(-float(self))  # a sign flip, not an addition

    def __abs__(self) -> CF:
        return CF(abs(float(self)))


def _counting_sqrt(x: float) -> CF:
    COUNT["sqrt"] += 1
    return CF(math.sqrt(float(x)))


@contextmanager
def counting(monkeypatch: pytest.MonkeyPatch) -> Iterator[Counter[str]]:
    COUNT.clear()
    with monkeypatch.context() as m:
        m.setattr(spheres, "_sqrt", _counting_sqrt)
        yield COUNT


def _cf3(p: tuple[float, float, float]) -> tuple[CF, CF, CF]:
    return (CF(p[0]), CF(p[1]), CF(p[2]))


H = 7.62
B1, B2, B3 = (-40.46, -25.0, H), (-40.46, 25.0, H), (40.46, 25.0, H)
RADII = (38.0, 48.0, 58.0)


def _count(
    monkeypatch: pytest.MonkeyPatch, fn: Callable[..., tuple[float, float, float]], *args: Any
) -> tuple[dict[str, int], tuple[float, float, float]]:
    with counting(monkeypatch) as c:
        out = fn(*args)
        counts = {k: c[k] for k in ("add", "mul", "sqrt", "pow")}
    return counts, out


def test_simplified_paper_faithful_count(monkeypatch: pytest.MonkeyPatch) -> None:
    counts, out = _count(
        monkeypatch,
        kin.three_spheres_equal_height,
        _cf3(B1),
        _cf3(B2),
        _cf3(B3),
        *(CF(r) for r in RADII),
    )
    assert all(isinstance(v, CF) for v in out)  # every result flowed through the counter
    assert out == pytest.approx(kin.three_spheres_equal_height(B1, B2, B3, *RADII), abs=0)
    assert counts == {"add": 18, "mul": 18, "sqrt": 1, "pow": 0}
    # Against the paper's own tally for the new algorithm: 25 / 31 / 1.
    assert counts["add"] <= 25 and counts["mul"] <= 31


def test_simplified_hoisted_per_tick_count(monkeypatch: pytest.MonkeyPatch) -> None:
    geom = kin.Geometry([B1, B2, B3])
    sd = geom._seed
    assert isinstance(sd, spheres._EqualSeed)
    floats: dict[str, Any] = {
        f.name: CF(getattr(sd, f.name))
        for f in dataclasses.fields(sd)
        if isinstance(getattr(sd, f.name), float)
    }
    csd = dataclasses.replace(sd, **floats)
    counts, out = _count(monkeypatch, spheres._seed_equal, csd, *(CF(r) for r in RADII))
    assert all(isinstance(v, CF) for v in out)
    assert out == pytest.approx(kin.three_spheres_equal_height(B1, B2, B3, *RADII), abs=1e-12)
    assert counts == {"add": 11, "mul": 9, "sqrt": 1, "pow": 0}


def test_general_count(monkeypatch: pytest.MonkeyPatch) -> None:
    cs = [(-30.0, -20.0, 9.0), (-25.0, 22.0, 6.0), (35.0, 18.0, 12.0)]
    p = (1.0, 2.0, -3.0)
    r = [math.dist(p, c) for c in cs]
    counts, out = _count(
        monkeypatch, kin.three_spheres, *(_cf3(c) for c in cs), *(CF(v) for v in r)
    )
    assert all(isinstance(v, CF) for v in out)
    assert out == pytest.approx(p, abs=1e-10)
    assert counts == {"add": 31, "mul": 37, "sqrt": 1, "pow": 0}
    # Against the paper's tally for the original general algorithm: 48 / 62 / 1.
    assert counts["add"] < 48 and counts["mul"] < 62


def test_general_hoisted_per_tick_count(monkeypatch: pytest.MonkeyPatch) -> None:
    cs = [(-30.0, -20.0, 9.0), (-25.0, 22.0, 6.0), (35.0, 18.0, 12.0)]
    geom = kin.Geometry(cs)
    sd = geom._seed
    assert isinstance(sd, spheres._GeneralSeed)
    floats: dict[str, Any] = {
        f.name: CF(getattr(sd, f.name))
        for f in dataclasses.fields(sd)
        if isinstance(getattr(sd, f.name), float)
    }
    csd = dataclasses.replace(sd, **floats)
    p = (1.0, 2.0, -3.0)
    r = [math.dist(p, c) for c in cs]
    counts, out = _count(monkeypatch, spheres._seed_general, csd, *(CF(v) for v in r))
    assert all(isinstance(v, CF) for v in out)
    assert out == pytest.approx(p, abs=1e-10)
    assert counts == {"add": 16, "mul": 18, "sqrt": 1, "pow": 0}


def test_module_docstring_states_the_counts() -> None:
    doc = spheres.__doc__ or ""
    for text in ("25 / 31 / 1", "48 / 62 / 1", "18 / 18 / 1", "11 / 9 / 1", "31 / 37 / 1"):
        assert text in doc
    assert "16 / 18 / 1" in doc
