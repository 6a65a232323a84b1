"""The one table of command rules: its shape, the loop obeying it for every verb in every state,
and the table in docs/operating.md being the table's."""

from __future__ import annotations

import pathlib
from typing import Any

import pytest

from controller.core.commands import (
    VERBS,
    Arm,
    CommandRefused,
    Disarm,
    Estop,
    Home,
    Move,
    Path,
    Pretension,
    Reset,
    Setpoint,
    Shaper,
    Stop,
    Velocity,
)
from controller.core.states import (
    COMMAND_RULES,
    COMMAND_VERBS,
    State,
    command_table_markdown,
    refusal,
)
from tests.fakes import make_config
from tests.service.test_loop import RATE_HZ, Rig

OPERATING = pathlib.Path(__file__).resolve().parents[2] / "docs" / "operating.md"


def test_every_state_rules_every_verb() -> None:
    assert set(COMMAND_RULES) == set(State)
    assert set(COMMAND_VERBS) == set(VERBS) | {"setpoint", "velocity"}
    for state, rules in COMMAND_RULES.items():
        assert set(rules) == set(COMMAND_VERBS), state
        for verb, reason in rules.items():
            assert reason is None or reason.strip(), (state, verb)


def test_estop_is_accepted_everywhere_and_latched_states_take_only_reset() -> None:
    for state in State:
        assert refusal(state, "estop") is None
    for state in (State.FAULT, State.ESTOPPED):
        accepted = {v for v in COMMAND_VERBS if refusal(state, v) is None}
        assert accepted == {"estop", "reset"}
    assert refusal(State.ESTOPPED, "stop") == "estop is latched: reset first"
    for verb in ("move", "path", "setpoint", "velocity"):
        assert {s for s in State if refusal(s, verb) is None} == {State.HOLDING, State.MOVING}


def test_the_operating_guide_shows_the_table_of_the_code() -> None:
    text = OPERATING.read_text()
    assert command_table_markdown() in text


def _in_state(state: State) -> Rig:
    """A fresh rig (fake driver and clock) brought to `state`."""
    # Drives of a real rig (a kinematic simulator has nothing to pre-tension against).
    rig = Rig(make_config(loop={"rate_hz": RATE_HZ}, sim={"enabled": False, "plant": "physical"}))
    rig.tick(2)
    if state is State.DISARMED:
        return rig
    if state is State.ESTOPPED:
        rig.ctl.submit(Estop())
        rig.tick()
        return rig
    if state is State.ARMING:
        rig.driver.no_closed_loop = {rig.ctl.node_ids[0]}
        rig.do(Arm())
        return rig
    rig.arm()
    if state is State.PRETENSIONING:
        rig.do(Pretension(rig.start))
    elif state is State.MOVING:
        s = rig.start
        rig.do(Move((s[0] + 2.0, s[1], s[2])))
    elif state is State.FAULT:
        rig.driver.axis_error[rig.ctl.node_ids[1]] = 0x800
        rig.tick()
        rig.driver.axis_error.clear()
    return rig


def _command(verb: str, rig: Rig) -> Any:
    s = rig.start
    near = (s[0] + 0.1, s[1], s[2])
    return {
        "estop": Estop(),
        "arm": Arm(),
        "disarm": Disarm(),
        "reset": Reset(),
        "home": Home(s),
        "pretension": Pretension(s),
        "move": Move(near),
        "path": Path((near,)),
        "setpoint": Setpoint(near),
        "velocity": Velocity((0.1, 0.0, 0.0)),
        "stop": Stop(),
        "shaper": Shaper("zv", 5.0),
    }[verb]


@pytest.mark.parametrize("state", list(State))
@pytest.mark.parametrize("verb", COMMAND_VERBS)
def test_the_loop_follows_the_table(state: State, verb: str) -> None:
    rig = _in_state(state)
    assert rig.state() is state, rig.ctl.reason
    fut = rig.ctl.submit(_command(verb, rig))
    rig.tick()
    assert fut.done()
    exc = fut.exception(timeout=0)
    why = refusal(state, verb)
    if why is None:
        assert exc is None, exc
        assert fut.result(timeout=0)["ok"] is True
    else:
        assert isinstance(exc, CommandRefused), (state, verb)
        assert str(exc).startswith(f"not allowed in {state.value}")
        assert str(exc).endswith(why)
        if state is State.FAULT:
            assert str(rig.ctl.reason) in str(exc)  # names the fault
        # A refusal changes nothing.
        if state is not State.MOVING:
            assert rig.state() is state


def test_stop_in_estopped_is_refused_and_changes_nothing() -> None:
    rig = _in_state(State.ESTOPPED)
    n = len(rig.driver.commands)
    fut = rig.ctl.submit(Stop())
    rig.tick(int(RATE_HZ / 10))
    exc = fut.exception(timeout=0)
    assert isinstance(exc, CommandRefused)
    assert "not allowed in ESTOPPED" in str(exc) and "reset first" in str(exc)
    assert rig.state() is State.ESTOPPED and len(rig.driver.commands) == n
