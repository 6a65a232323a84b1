"""Controller states and the one table of allowed transitions.

DISARMED -> ARMING -> HOLDING <-> MOVING, plus FAULT and ESTOPPED. ESTOPPED is reachable from
every state, FAULT from every armed or arming state; `reset` takes FAULT/ESTOPPED back to
DISARMED. Every transition the controller makes goes through `check_transition`.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import StrEnum
from types import MappingProxyType


class State(StrEnum):
    """Controller state; the value is the name published on `<prefix>/state`."""

    DISARMED = "DISARMED"
    ARMING = "ARMING"
    HOLDING = "HOLDING"
    MOVING = "MOVING"
    FAULT = "FAULT"
    ESTOPPED = "ESTOPPED"


class InvalidTransition(RuntimeError):
    """A state change that the transition table does not allow."""


_S = State

TRANSITIONS: Mapping[State, frozenset[State]] = MappingProxyType(
    {
        _S.DISARMED: frozenset({_S.ARMING, _S.ESTOPPED}),
        _S.ARMING: frozenset({_S.HOLDING, _S.DISARMED, _S.FAULT, _S.ESTOPPED}),
        _S.HOLDING: frozenset({_S.MOVING, _S.DISARMED, _S.FAULT, _S.ESTOPPED}),
        _S.MOVING: frozenset({_S.HOLDING, _S.DISARMED, _S.FAULT, _S.ESTOPPED}),
        _S.FAULT: frozenset({_S.DISARMED, _S.ESTOPPED}),
        _S.ESTOPPED: frozenset({_S.DISARMED}),
    }
)
"""Allowed transitions: `TRANSITIONS[a]` is the set of states reachable from `a` in one step."""

ARMED_STATES: frozenset[State] = frozenset({_S.HOLDING, _S.MOVING})
"""States in which the motors are commanded from the motion planner."""


def allowed(a: State, b: State) -> bool:
    """Return True if the controller may go from state `a` to state `b`."""
    return b in TRANSITIONS[a]


def check_transition(a: State, b: State) -> None:
    """Raise InvalidTransition unless the controller may go from `a` to `b`."""
    if b not in TRANSITIONS[a]:
        raise InvalidTransition(f"transition {a.value} -> {b.value} is not allowed")
