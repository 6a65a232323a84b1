"""The controller's parts: the command table drives one handler per queued verb."""

from __future__ import annotations

from controller.core.states import COMMAND_VERBS
from controller.service.control import commands
from controller.service.loop import Controller

# Taken outside the command queue: e-stop by its flag, set-points and velocity samples streamed.
NOT_QUEUED = {"estop", "setpoint", "velocity"}


def test_every_verb_of_the_command_table_has_a_command_type() -> None:
    assert sorted(commands._VERBS.values()) == sorted(COMMAND_VERBS)


def test_every_queued_verb_has_one_handler_and_no_other_verb_has_one() -> None:
    assert set(commands._HANDLERS) == set(COMMAND_VERBS) - NOT_QUEUED
    for verb, handler in commands._HANDLERS.items():
        assert getattr(Controller, handler.__name__) is handler, verb


def test_the_controller_is_assembled_from_every_part() -> None:
    parts = {c.__module__ for c in Controller.__mro__}
    assert {
        "controller.service.control.base",
        "controller.service.control.faults",
        "controller.service.control.homing",
        "controller.service.control.commands",
        "controller.service.control.step",
        "controller.service.control.status",
    } <= parts
