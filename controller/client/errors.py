"""The errors the client library raises: each names what went wrong, so a program can tell a
refusal from an absent daemon, a timeout or its own bad input.

Every one of them is a `ClientError`. Nothing is sent when `InputError` or `UsageError` is
raised.
"""

from __future__ import annotations


class ClientError(Exception):
    """Base of every error the client library raises on purpose."""


class DaemonAbsent(ClientError, RuntimeError):
    """No daemon answered: nothing listening on the endpoint, wrong prefix, or no reply (or no
    pose sample) in time.

    `live` names the prefixes of the daemons that are alive on the same network, when the
    caller looked them up (`controller.client.transport.live_prefixes`), for the message."""

    live: tuple[str, ...] = ()


class Refused(ClientError, RuntimeError):
    """The daemon answered with an error reply; the message is its reason, verbatim."""


class Failed(Refused):
    """The daemon accepted the command, which then did not complete: the robot went FAULT,
    ESTOPPED or DISARMED, or the motion ended short of its end (stopped, replaced), while it was
    followed; the message says what happened. (A `Refused`, for the handlers that only need
    "it did not work".)"""


class InputError(ClientError, ValueError):
    """The caller's input (numbers, points, a path or job file) is invalid; nothing was sent."""


class UsageError(ClientError, ValueError):
    """A connection setting that cannot be used (an endpoint, a Zenoh configuration file);
    nothing was sent."""


class WaitTimeout(ClientError, TimeoutError):
    """A wait (arrival, a pre-tension, a job's rest) did not end within its deadline; the robot
    goes on with what it was doing."""


class Cancelled(ClientError):
    """The caller cancelled a wait or a stream (an `asyncio` task cancelled, a `cancel` event
    set from another thread); the robot was braked to a hold unless told not to."""
