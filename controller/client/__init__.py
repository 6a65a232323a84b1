"""cablebot's Python client library: drive and watch a robot from a program (docs/python.md).

```python
from controller.client import Robot

with Robot() as robot:                      # tcp/127.0.0.1:7447, prefix cablebot/default
    print(robot.status().state)
    robot.move((5.0, 3.0, 2.5))
    print(robot.wait().text())              # arrived: seq ... state HOLDING x=+5.000 ...
```

- `Robot`: one daemon's robot: `status`, `pose`, `poses`, `on_pose`, `truth`; every verb
  of the command table (`move`, `path`, `stop`, `estop`, `arm`, `disarm`, `reset`, `home`,
  `pretension`, `setpoint`, `velocity`, or any by name with `command`); `wait` for arrival,
  `wait_armed`, `wait_pretension`; `stream_path` / `iter_path` for paths of any length.
- `controller.client.job`: G-code jobs, checked against the daemon's robot and streamed.
- `controller.client.aio.AsyncRobot`: the same for programs that run an asyncio event loop.
- `discover` / `list_daemons`: the live daemons on a Zenoh network.
- Errors (`controller.client.errors`): `Refused` (the daemon's reason), `Failed` (accepted,
  then did not complete), `DaemonAbsent`, `WaitTimeout`, `InputError` and `UsageError`
  (nothing sent); all are `ClientError`s.

The daemon is the authority on its robot: this library never plans or checks motion with a
robot file of its own; the daemon's limits decide, and its refusals come back as `Refused`.
"""

from __future__ import annotations

from controller.client.arrival import ARRIVED_TOL_M, ArrivalProgress
from controller.client.errors import (
    ClientError,
    DaemonAbsent,
    Failed,
    InputError,
    Refused,
    UsageError,
    WaitTimeout,
)
from controller.client.inputs import load_path_file
from controller.client.link import PoseStream, RobotLink, discover, list_daemons
from controller.client.model import (
    AxisStatus,
    DaemonInfo,
    PathQueue,
    Pose,
    PretensionResult,
    PretensionStatus,
    Reply,
    StateChange,
    Status,
    Truth,
    Vec3,
)
from controller.client.robot import Robot
from controller.client.signals import signals_interrupt
from controller.client.stream import LOW_WATER_S, StreamProgress
from controller.client.transport import DEFAULT_ENDPOINT, DEFAULT_PREFIX

__all__ = [
    "ARRIVED_TOL_M",
    "DEFAULT_ENDPOINT",
    "DEFAULT_PREFIX",
    "LOW_WATER_S",
    "ArrivalProgress",
    "AxisStatus",
    "ClientError",
    "DaemonAbsent",
    "DaemonInfo",
    "Failed",
    "InputError",
    "PathQueue",
    "Pose",
    "PoseStream",
    "PretensionResult",
    "PretensionStatus",
    "Refused",
    "Reply",
    "Robot",
    "RobotLink",
    "StateChange",
    "Status",
    "StreamProgress",
    "Truth",
    "UsageError",
    "Vec3",
    "WaitTimeout",
    "discover",
    "list_daemons",
    "load_path_file",
    "signals_interrupt",
]
