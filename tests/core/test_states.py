"""The state table: every allowed and every forbidden transition."""

from __future__ import annotations

import itertools

import pytest

from controller.core.states import TRANSITIONS, InvalidTransition, State, allowed, check_transition

S = State


def test_every_state_has_an_entry() -> None:
    assert set(TRANSITIONS) == set(State)


def test_estop_reachable_from_every_other_state() -> None:
    for s in State:
        if s is not S.ESTOPPED:
            assert allowed(s, S.ESTOPPED), s


def test_fault_reachable_only_when_the_motors_are_on() -> None:
    on = {S.ARMING, S.HOLDING, S.MOVING, S.PRETENSIONING}
    assert {s for s in State if allowed(s, S.FAULT)} == on


def test_pretension_starts_disarmed_or_holding_and_ends_holding() -> None:
    assert {s for s in State if allowed(s, S.PRETENSIONING)} == {S.DISARMED, S.HOLDING}
    assert TRANSITIONS[S.PRETENSIONING] == {S.HOLDING, S.DISARMED, S.FAULT, S.ESTOPPED}


def test_reset_paths() -> None:
    assert TRANSITIONS[S.FAULT] == {S.DISARMED, S.ESTOPPED}
    assert TRANSITIONS[S.ESTOPPED] == {S.DISARMED}


def test_main_sequence() -> None:
    for a, b in [
        (S.DISARMED, S.ARMING),
        (S.ARMING, S.HOLDING),
        (S.HOLDING, S.MOVING),
        (S.MOVING, S.HOLDING),
        (S.HOLDING, S.DISARMED),
    ]:
        check_transition(a, b)


@pytest.mark.parametrize(
    ("a", "b"),
    [
        (S.DISARMED, S.HOLDING),
        (S.DISARMED, S.MOVING),
        (S.DISARMED, S.FAULT),
        (S.ARMING, S.MOVING),
        (S.FAULT, S.HOLDING),
        (S.FAULT, S.MOVING),
        (S.ESTOPPED, S.HOLDING),
        (S.ESTOPPED, S.FAULT),
        (S.PRETENSIONING, S.MOVING),
        (S.MOVING, S.PRETENSIONING),
        (S.FAULT, S.PRETENSIONING),
    ],
)
def test_forbidden(a: State, b: State) -> None:
    with pytest.raises(InvalidTransition, match=f"{a.value} -> {b.value}"):
        check_transition(a, b)


def test_no_self_transitions() -> None:
    for s in State:
        assert not allowed(s, s)


def test_table_counts() -> None:
    pairs = [(a, b) for a, b in itertools.product(State, State) if allowed(a, b)]
    assert len(pairs) == 3 + 4 + 5 + 4 + 4 + 2 + 1
    assert str(S.MOVING) == "MOVING"
