"""controller.commands: JSON parsing of operator commands (schema, finite numbers)."""

from __future__ import annotations

import contextlib
import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.commands import (
    VERBS,
    Arm,
    CommandError,
    Disarm,
    Estop,
    Home,
    Move,
    Path,
    Reset,
    Setpoint,
    Stop,
    parse_command,
)
from controller.motion import MIN_SPEED_MPS

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
vec3 = st.tuples(finite, finite, finite)


def test_every_verb_parses() -> None:
    assert parse_command("move", b'{"position_m": [1, 2, 3]}') == Move((1.0, 2.0, 3.0))
    assert parse_command("move", '{"position_m": [1, 2, 3], "speed_mps": 0.5}') == Move(
        (1.0, 2.0, 3.0), 0.5
    )
    assert parse_command("move", '{"position_m": [1, 2, 3], "speed_mps": null}') == Move(
        (1.0, 2.0, 3.0)
    )
    assert parse_command("path", b'{"points_m": [[0, 0, 1], [1, 0, 1]]}') == Path(
        ((0.0, 0.0, 1.0), (1.0, 0.0, 1.0))
    )
    assert parse_command("home", b'{"position_m": [0, 0, 2]}') == Home((0.0, 0.0, 2.0))
    assert parse_command("setpoint", b'{"position_m": [0, 0, 2]}') == Setpoint((0.0, 0.0, 2.0))
    for verb, cls in (
        ("stop", Stop),
        ("estop", Estop),
        ("arm", Arm),
        ("disarm", Disarm),
        ("reset", Reset),
    ):
        assert parse_command(verb, None) == cls()
        assert parse_command(verb, b"") == cls()
        assert parse_command(verb, b"  {} ") == cls()
    assert set(VERBS) == {"move", "path", "stop", "estop", "arm", "disarm", "reset", "home"}


def test_position_values_are_floats() -> None:
    cmd = parse_command("move", b'{"position_m": [1, 2, 3]}')
    assert isinstance(cmd, Move)
    assert all(type(v) is float for v in cmd.position_m)


@pytest.mark.parametrize(
    ("verb", "payload", "reason"),
    [
        ("move", b"{", "malformed JSON"),
        ("move", b"\xff\xfe", "malformed JSON"),
        ("move", b"null", "expected a JSON object"),
        ("move", b'"move"', "expected a JSON object"),
        ("move", b"{}", "missing field(s): position_m"),
        ("move", b'{"position_m": [0, 0, 1], "x": 1}', "unknown field(s): x"),
        ("move", b'{"position_m": [0, 0, 1, 2]}', "position_m: expected [x, y, z]"),
        ("move", b'{"position_m": {"x": 0}}', "position_m: expected [x, y, z]"),
        ("move", b'{"position_m": [0, 0, true]}', "position_m[2]: expected a number, got bool"),
        ("move", b'{"position_m": [0, "1", 0]}', "position_m[1]: expected a number, got str"),
        ("move", b'{"position_m": [0, 0, NaN]}', "non-finite number NaN"),
        ("move", b'{"position_m": [Infinity, 0, 0]}', "non-finite number Infinity"),
        ("move", b'{"position_m": [0, -Infinity, 0]}', "non-finite number -Infinity"),
        ("move", b'{"position_m": [0, 0, 1e999]}', "position_m[2]: must be a finite number"),
        (
            "move",
            b'{"position_m": [0, 0, 1' + b"0" * 400 + b"]}",
            "position_m[2]: must be a finite",
        ),
        ("move", b'{"position_m": [0, 0, 1], "speed_mps": 0}', "speed_mps: must be > 0"),
        ("move", b'{"position_m": [0, 0, 1], "speed_mps": -2}', "speed_mps: must be > 0"),
        ("path", b'{"points_m": []}', "points_m: expected a non-empty list"),
        ("path", b'{"points_m": [0, 0, 1]}', "points_m[0]: expected [x, y, z]"),
        ("path", b'{"points_m": [[0, 0, 1], [0, 0, NaN]]}', "non-finite number NaN"),
        ("home", b'{"position_m": null}', "position_m: expected [x, y, z]"),
        ("stop", b'{"now": 1}', "unknown field(s): now"),
        ("arm", b"[]", "expected a JSON object"),
        ("fly", b"{}", "unknown command 'fly'"),
    ],
)
def test_malformed_payloads(verb: str, payload: bytes, reason: str) -> None:
    with pytest.raises(CommandError) as info:
        parse_command(verb, payload)
    assert reason in str(info.value)


def test_too_many_path_points() -> None:
    payload = json.dumps({"points_m": [[0, 0, 1]] * 10_001})
    with pytest.raises(CommandError, match="at most 10000 points"):
        parse_command("path", payload)
    assert isinstance(parse_command("path", json.dumps({"points_m": [[0, 0, 1]] * 10_000})), Path)


@given(vec3, st.one_of(st.none(), st.floats(min_value=MIN_SPEED_MPS, max_value=100.0)))
def test_move_round_trips_any_finite_position(
    p: tuple[float, float, float], v: float | None
) -> None:
    body: dict[str, object] = {"position_m": list(p)}
    if v is not None:
        body["speed_mps"] = v
    cmd = parse_command("move", json.dumps(body))
    assert cmd == Move(p, v)


@given(vec3, st.integers(0, 2), st.sampled_from([math.nan, math.inf, -math.inf]))
def test_any_non_finite_coordinate_is_refused(
    p: tuple[float, float, float], i: int, bad: float
) -> None:
    q = list(p)
    q[i] = bad
    with pytest.raises(CommandError):
        parse_command("move", json.dumps({"position_m": q}))  # json.dumps writes NaN/Infinity


@given(st.sampled_from([*VERBS, "setpoint"]), st.binary(max_size=64))
def test_junk_never_raises_anything_but_command_error(verb: str, junk: bytes) -> None:
    with contextlib.suppress(CommandError):
        parse_command(verb, junk)


@given(
    st.sampled_from([*VERBS, "setpoint"]),
    st.recursive(
        st.none()
        | st.booleans()
        | st.floats()
        | st.integers()
        | st.integers(min_value=10**308, max_value=10**400)
        | st.text(max_size=5),
        lambda inner: (
            st.lists(inner, max_size=4)
            | st.dictionaries(
                st.sampled_from(["position_m", "points_m", "speed_mps", "x"]), inner, max_size=3
            )
        ),
        max_leaves=10,
    ),
)
def test_arbitrary_json_gives_a_command_or_command_error(verb: str, obj: object) -> None:
    try:
        cmd = parse_command(verb, json.dumps(obj))
    except CommandError:
        return
    for field in ("position_m", "speed_mps"):
        value = getattr(cmd, field, None)
        values = value if isinstance(value, tuple) else [value]
        assert all(v is None or math.isfinite(v) for v in values)
    for point in getattr(cmd, "points_m", ()):
        assert all(math.isfinite(v) for v in point)
