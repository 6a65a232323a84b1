"""controller.core.commands: JSON parsing of operator commands (schema, finite numbers)."""

from __future__ import annotations

import contextlib
import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.core.commands import (
    C_DECODE_MAX_BYTES,
    MAX_JSON_DEPTH,
    MAX_PATH_POINTS,
    MAX_PAYLOAD_BYTES,
    PATH_STREAM_HINT,
    QUOTE_CHARS,
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
    Velocity,
    check_payload_size,
    clip,
    parse_command,
    quote,
)
from controller.core.motion import MIN_SPEED_MPS

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
    assert parse_command("velocity", b'{"velocity_mps": [0.5, 0, -1]}') == Velocity(
        (0.5, 0.0, -1.0)
    )
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
    assert set(VERBS) == {
        "move",
        "path",
        "stop",
        "estop",
        "arm",
        "disarm",
        "reset",
        "home",
        "pretension",
        "shaper",
    }


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
    payload = json.dumps({"points_m": [[0, 0, 1]] * (MAX_PATH_POINTS + 1)})
    with pytest.raises(CommandError, match=f"at most {MAX_PATH_POINTS} points"):
        parse_command("path", payload)
    ok = json.dumps({"points_m": [[0, 0, 1]] * MAX_PATH_POINTS})
    assert isinstance(parse_command("path", ok), Path)


def test_the_longest_path_fits_the_byte_cap_even_pretty_printed() -> None:
    worst = -1.2345678901234567e-05  # the longest repr of a float
    points = [[worst, worst, worst]] * MAX_PATH_POINTS
    speed = 0.0012345678901234567  # as long, and above the minimum speed
    payload = json.dumps({"points_m": points, "speed_mps": speed}, indent=2).encode()
    assert len(payload) <= MAX_PAYLOAD_BYTES["path"]
    cmd = parse_command("path", payload)
    assert isinstance(cmd, Path) and len(cmd.points_m) == MAX_PATH_POINTS


# A valid payload per verb (and per streamed sample), to pad to the byte cap with whitespace.
VALID = {
    "move": b'{"position_m": [0, 0, 1]}',
    "path": b'{"points_m": [[0, 0, 1]]}',
    "home": b'{"position_m": [0, 0, 1]}',
    "pretension": b'{"position_m": [0, 0, 1]}',
    "setpoint": b'{"position_m": [0, 0, 1]}',
    "velocity": b'{"velocity_mps": [0, 0, 1]}',
    "shaper": b'{"type": "zvd", "frequency_hz": 40}',
    **{verb: b"{}" for verb in ("stop", "estop", "arm", "disarm", "reset")},
}


def test_every_verb_has_a_byte_cap() -> None:
    assert set(MAX_PAYLOAD_BYTES) == {*VERBS, "setpoint", "velocity"} == set(VALID)
    assert max(MAX_PAYLOAD_BYTES.values()) <= 128 * 1024


@pytest.mark.parametrize("verb", sorted(VALID))
def test_a_payload_over_the_byte_cap_is_refused_before_decoding(verb: str) -> None:
    limit = MAX_PAYLOAD_BYTES[verb]
    at_limit = VALID[verb] + b" " * (limit - len(VALID[verb]))
    parse_command(verb, at_limit)  # valid, exactly at the cap
    parse_command(verb, at_limit.decode())
    for too_big in (at_limit + b" ", at_limit.decode() + " ", b"[" * 10_000_000):
        with pytest.raises(CommandError) as info:
            parse_command(verb, too_big)
        # a path names the points it carries and how to send more
        hint = f"; {PATH_STREAM_HINT}" if verb == "path" else ""
        assert str(info.value) == (
            f"payload too large: {len(too_big)} bytes, {verb} takes at most {limit}{hint}"
        )
    with pytest.raises(CommandError, match="payload too large"):
        check_payload_size(verb, limit + 1)
    check_payload_size(verb, limit)
    with pytest.raises(CommandError, match="unknown command 'fly'"):
        check_payload_size("fly", 0)


def _nested(depth: int, inner: bytes = b"1") -> bytes:
    return b"[" * depth + inner + b"]" * depth


def _deep_payloads(limit: int) -> list[bytes]:
    """Nested payloads within the byte cap `limit`: 1200 levels where they fit."""
    d = min(1200, (limit - 20) // 2)
    return [
        _nested(d),  # 1200 levels: deeper than the decoder's recursion limit
        b'{"position_m": ' + _nested(d - 10) + b"}",
        b'{"points_m": ' + _nested(d - 10) + b"}",
        b"{" * (2 * d),  # unclosed
        b'{"a": ' * (d // 4) + b"1" + b"}" * (d // 4),
        _nested(MAX_JSON_DEPTH + 1),
    ]


@pytest.mark.parametrize("verb", sorted(VALID))
@pytest.mark.parametrize("case", range(6))
def test_deep_nesting_is_refused_as_malformed(verb: str, case: int) -> None:
    payload = _deep_payloads(MAX_PAYLOAD_BYTES[verb])[case]
    assert len(payload) <= MAX_PAYLOAD_BYTES[verb]
    with pytest.raises(CommandError) as info:
        parse_command(verb, payload)
    assert str(info.value) == f"nested too deeply: at most {MAX_JSON_DEPTH} levels of [ and {{"


def test_brackets_hidden_in_strings_meet_the_decoders_limit() -> None:
    # ["]", ["]", ...: the byte scan pairs each [ with the ] in the string; the decoder's own
    # recursion limit refuses it with the same reason.
    payload = b'{"points_m": ' + b'["]", ' * 1200 + b"1" + b"]" * 1200 + b"}"
    assert len(payload) <= MAX_PAYLOAD_BYTES["path"]
    with pytest.raises(CommandError) as info:
        parse_command("path", payload)
    assert str(info.value) == f"nested too deeply: at most {MAX_JSON_DEPTH} levels of [ and {{"


def _padded(payload: bytes) -> bytes:
    """`payload` with trailing whitespace beyond C_DECODE_MAX_BYTES: the same JSON, decoded by
    the interruptible scanner."""
    return payload + b" " * (C_DECODE_MAX_BYTES + 1 - len(payload))


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (b'{"points_m": [[0, 0, 1], [0, 0, NaN]]}', "non-finite number NaN"),
        (b'{"points_m": [[0, 0, 1], [0, 0, Infinity]]}', "non-finite number Infinity"),
        (b'{"points_m": [[0, 0, 1], [0, 0 1]]}', "malformed JSON"),
        (b'{"points_m": [[0, 0, 1]], "x": 1}', "unknown field(s): x"),
        (b'{"points_m": [[0, 0, 1e999]]}', "points_m[0][2]: must be a finite number"),
        (b'{"points_m": [[0, 0, 1]]} []', "malformed JSON: Extra data"),
        (b'\xff{"points_m": [[0, 0, 1]]}', "malformed JSON"),
        (b'{"points_m": ' + b'["]", ' * 1200 + b"1" + b"]" * 1200 + b"}", "nested too deeply"),
    ],
)
def test_a_large_payload_is_judged_as_a_small_one(payload: bytes, reason: str) -> None:
    for data in (payload, _padded(payload)):
        with pytest.raises(CommandError) as info:
            parse_command("path", data)
        assert reason in str(info.value)


def test_a_large_valid_path_decodes_exactly() -> None:
    points = [[i * 0.001, -i * 1e-7, 2.0 + i] for i in range(MAX_PATH_POINTS)]
    payload = json.dumps({"points_m": points, "speed_mps": 0.25}).encode()
    assert len(payload) > C_DECODE_MAX_BYTES
    cmd = parse_command("path", payload)
    assert cmd == Path(tuple((float(x), float(y), float(z)) for x, y, z in points), 0.25)


@given(
    st.recursive(
        st.none() | st.booleans() | finite | st.integers() | st.text(max_size=5),
        lambda inner: (
            st.lists(inner, max_size=4)
            | st.dictionaries(st.sampled_from(["points_m", "speed_mps", "x"]), inner, max_size=3)
        ),
        max_leaves=12,
    )
)
def test_both_decoders_agree(obj: object) -> None:
    small = json.dumps(obj).encode()
    outcomes = []
    for data in (small, _padded(small)):
        try:
            outcomes.append(parse_command("path", data))
        except CommandError as exc:
            outcomes.append(str(exc))
    assert outcomes[0] == outcomes[1]


def test_nesting_up_to_the_cap_reaches_the_schema_check() -> None:
    with pytest.raises(CommandError, match=r"points_m\[0\]\[0\]: expected a number, got list"):
        parse_command("path", b'{"points_m": [[' + _nested(MAX_JSON_DEPTH - 3) + b", 0, 1]]}")


@pytest.mark.parametrize(
    ("verb", "payload"),
    [
        ("move", json.dumps({"position_m": [1.5] * 900})),
        ("move", json.dumps({"position_m": "x" * 3000})),
        ("move", json.dumps({"position_m": {f"k{i}": [i] * 9 for i in range(100)}})),
        ("move", json.dumps({"x" * 3000: 1})),
        ("path", json.dumps({f"field{i}" * 5: 1 for i in range(3000)})),
        ("path", json.dumps({"points_m": [[0, 0, 1], [[0] * 20000, 0, 1]]})),
        ("setpoint", json.dumps({"position_m": [[[1.0] * 400] * 2] * 3})),
        ("move", b'{"position_m": [0, 0, 1]' + b"\x00" * 1000),
        ("move", b'{"position_m": [0, 0, 1], "\n' + b"\n" * 1000 + b'": 1}'),
        ("move", b"\xff" * 4000),
    ],
)
def test_a_refusal_quotes_at_most_a_short_prefix_of_the_input(verb: str, payload: str) -> None:
    with pytest.raises(CommandError) as info:
        parse_command(verb, payload)
    reason = str(info.value)
    assert len(reason) <= 60 + QUOTE_CHARS, reason
    assert reason.isprintable(), reason


@given(st.text(max_size=300), st.integers(3, 120))
def test_clip_is_short_and_printable(text: str, limit: int) -> None:
    out = clip(text, limit)
    assert len(out) <= limit
    assert out.isprintable()
    if len(text) <= limit and text.isprintable():
        assert out == text


def test_quote_is_bounded_for_any_size() -> None:
    assert quote([1.0] * 1_000_000) == "[1.0, 1.0, 1.0, 1.0, ...]"
    assert len(quote("x" * 1_000_000)) <= QUOTE_CHARS
    assert len(quote({i: list(range(1000)) for i in range(1000)})) <= QUOTE_CHARS


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


def test_path_append_flag_parses_and_refuses_non_booleans() -> None:
    pts = ((0.0, 0.0, 1.0), (1.0, 0.0, 1.0))
    base = '{"points_m": [[0, 0, 1], [1, 0, 1]]'
    assert parse_command("path", base + "}") == Path(pts)
    assert parse_command("path", base + ', "append": true}') == Path(pts, None, True)
    assert parse_command("path", base + ', "append": false, "speed_mps": 0.5}') == Path(
        pts, 0.5, False
    )
    assert parse_command("path", base + ', "append": null}') == Path(pts)
    for bad in ("1", "0", '"true"', "[true]", "{}"):
        with pytest.raises(CommandError, match="append: expected true or false"):
            parse_command("path", base + f', "append": {bad}}}')
    # the same caps and finite checks as a path that replaces
    with pytest.raises(CommandError, match="non-finite"):
        parse_command("path", '{"points_m": [[0, 0, NaN]], "append": true}')
    too_many = json.dumps({"points_m": [[0, 0, 1]] * (MAX_PATH_POINTS + 1), "append": True})
    with pytest.raises(CommandError, match="at most"):
        parse_command("path", too_many)
    with pytest.raises(CommandError, match="append"):
        parse_command("move", '{"position_m": [0, 0, 1], "append": true}')


def test_a_path_too_long_for_one_command_names_the_point_limit_and_how_to_stream() -> None:
    points = [[0.0, 0.0, 1.0 + i * 1e-4] for i in range(10_000)]
    with pytest.raises(CommandError) as info:
        parse_command("path", json.dumps({"points_m": points}))  # 490 kB: over the byte cap
    reason = str(info.value)
    assert reason.startswith("payload too large: ") and "1,000 points a command" in reason
    assert '"append": true' in reason
    with pytest.raises(CommandError) as info:  # within the bytes, over the points
        parse_command("path", json.dumps({"points_m": [[0, 0, 1]] * 1001}))
    assert str(info.value) == f"points_m: at most 1000 points, got 1001; {PATH_STREAM_HINT}"
