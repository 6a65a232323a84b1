"""Controller states, the one table of allowed transitions and the one table of command rules.

DISARMED -> ARMING -> HOLDING <-> MOVING, plus PRETENSIONING (the reels pull in torque control
before the home pose is declared; from DISARMED or HOLDING, ending in HOLDING), FAULT and
ESTOPPED. ESTOPPED is reachable from every state, FAULT from every armed, arming or
pretensioning state; `reset` takes FAULT/ESTOPPED back to DISARMED. Every transition the
controller makes goes through `check_transition`.

`COMMAND_RULES` says, for every state, which verbs it accepts and why it refuses the others;
the control loop asks `refusal(state, verb)` for every verb it receives (streamed set-points
and velocity samples included), and the state table of docs/operating.md is
`command_table_markdown()`.
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
    PRETENSIONING = "PRETENSIONING"
    FAULT = "FAULT"
    ESTOPPED = "ESTOPPED"


class InvalidTransition(RuntimeError):
    """A state change that the transition table does not allow."""


_S = State

TRANSITIONS: Mapping[State, frozenset[State]] = MappingProxyType(
    {
        _S.DISARMED: frozenset({_S.ARMING, _S.PRETENSIONING, _S.ESTOPPED}),
        _S.ARMING: frozenset({_S.HOLDING, _S.DISARMED, _S.FAULT, _S.ESTOPPED}),
        _S.HOLDING: frozenset({_S.MOVING, _S.PRETENSIONING, _S.DISARMED, _S.FAULT, _S.ESTOPPED}),
        _S.PRETENSIONING: frozenset({_S.HOLDING, _S.DISARMED, _S.FAULT, _S.ESTOPPED}),
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


# --------------------------------------------------------------------------------------------
# Command rules

COMMAND_VERBS: tuple[str, ...] = (
    "estop",
    "arm",
    "disarm",
    "reset",
    "home",
    "pretension",
    "move",
    "path",
    "setpoint",
    "velocity",
    "stop",
    "shaper",
)
"""Every verb the controller takes: the `cmd/<verb>` commands plus streamed `setpoint`s and
`velocity` samples (velocity input is allowed exactly where streamed set-points are)."""

_NOT_ARMED = "the motors are disarmed: arm first"
_ARMING = "arming: wait for HOLDING"
_ALREADY_ARMED = "already armed"
_NO_RESET = "nothing to reset: disarm idles the motors"
_FAULT = "the motors hold the last good set-point: reset first"
_ESTOP = "estop is latched: reset first"
_PRETENSIONING = "pretensioning: wait for HOLDING, or `stop` to end it where the reels are"

COMMAND_RULES: Mapping[State, Mapping[str, str | None]] = MappingProxyType(
    {
        _S.DISARMED: MappingProxyType(
            {
                "estop": None,
                "arm": None,
                "disarm": None,
                "reset": None,
                "home": None,
                "pretension": None,
                "move": _NOT_ARMED,
                "path": _NOT_ARMED,
                "setpoint": _NOT_ARMED,
                "velocity": _NOT_ARMED,
                "stop": "nothing to stop: the motors are disarmed",
                "shaper": None,
            }
        ),
        _S.ARMING: MappingProxyType(
            {
                "estop": None,
                "arm": "already arming",
                "disarm": None,
                "reset": "nothing to reset: disarm stops arming",
                "home": "arming: home when DISARMED or HOLDING",
                "pretension": "arming: home when DISARMED or HOLDING",
                "move": _ARMING,
                "path": _ARMING,
                "setpoint": _ARMING,
                "velocity": _ARMING,
                "stop": None,
                "shaper": None,
            }
        ),
        _S.HOLDING: MappingProxyType(
            {
                "estop": None,
                "arm": _ALREADY_ARMED,
                "disarm": None,
                "reset": _NO_RESET,
                "home": None,
                "pretension": None,
                "move": None,
                "path": None,
                "setpoint": None,
                "velocity": None,
                "stop": None,
                "shaper": None,
            }
        ),
        _S.MOVING: MappingProxyType(
            {
                "estop": None,
                "arm": _ALREADY_ARMED,
                "disarm": None,
                "reset": _NO_RESET,
                "home": "moving: stop first, then home while HOLDING",
                "pretension": "moving: stop first, then home while HOLDING",
                "move": None,
                "path": None,
                "setpoint": None,
                "velocity": None,
                "stop": None,
                "shaper": None,
            }
        ),
        _S.PRETENSIONING: MappingProxyType(
            {v: None if v in ("estop", "disarm", "stop") else _PRETENSIONING for v in COMMAND_VERBS}
        ),
        _S.FAULT: MappingProxyType(
            {v: None if v in ("estop", "reset") else _FAULT for v in COMMAND_VERBS}
        ),
        _S.ESTOPPED: MappingProxyType(
            {v: None if v in ("estop", "reset") else _ESTOP for v in COMMAND_VERBS}
        ),
    }
)
"""`COMMAND_RULES[state][verb]`: None if `state` accepts `verb`, else the refusal reason."""


def refusal(state: State, verb: str) -> str | None:
    """None if `state` accepts `verb`, else the reason it refuses it (from COMMAND_RULES).

    Raises KeyError for a verb that is not in COMMAND_VERBS.
    """
    return COMMAND_RULES[state][verb]


def command_table_markdown() -> str:
    """The table of what each state accepts and refuses (docs/operating.md), from COMMAND_RULES.

    One row per state: the accepted verbs, then the refused ones grouped by reason.
    """
    lines = [
        "| state | accepts | refuses (reason given) |",
        "| --- | --- | --- |",
    ]
    for state in State:
        rules = COMMAND_RULES[state]
        accepts = " ".join(f"`{v}`" for v in COMMAND_VERBS if rules[v] is None)
        by_reason: dict[str, list[str]] = {}
        for v in COMMAND_VERBS:
            reason = rules[v]
            if reason is not None:
                by_reason.setdefault(reason, []).append(v)
        refuses = "; ".join(
            " ".join(f"`{v}`" for v in verbs) + f": {reason}" for reason, verbs in by_reason.items()
        )
        lines.append(f"| {state.value} | {accepts} | {refuses or '-'} |")
    return "\n".join(lines) + "\n"
