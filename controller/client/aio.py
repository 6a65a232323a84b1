"""`AsyncRobot`: the client library for programs that run an asyncio event loop.

```python
import asyncio
from controller.client.aio import AsyncRobot

async def main() -> None:
    async with await AsyncRobot.connect("tcp/127.0.0.1:7447") as robot:
        await robot.move((1.0, 0.0, 2.0))
        await robot.wait(timeout_s=60.0)

asyncio.run(main())
```

Zenoh's Python API blocks (a query waits for its reply on the calling thread), so every
coroutine here runs the `Robot` method of the same name in a worker thread
(`asyncio.to_thread`); the pose arrives on the loop through `call_soon_threadsafe`. The event
loop never blocks. Cancelling brakes as an exception does in the threaded client: a cancelled
`wait` sets its cancel event (the worker sees it within half a second, brakes the robot to a
hold and ends); a cancelled stream finishes the step in flight, then closes the stream, which
brakes; an exception leaving `async with` while motion this robot sent may run brakes.
"""

from __future__ import annotations

import asyncio
import math
import threading
from collections.abc import AsyncGenerator, Callable, Generator, Iterable, Sequence
from contextlib import suppress
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import controller.client.transport as transport
from controller.client.arrival import ArrivalProgress
from controller.client.errors import DaemonAbsent
from controller.client.job import GcodeJob, JobProgress, JobResult, iter_job, load_gcode
from controller.client.model import Pose, PretensionResult, Reply, Status, Truth
from controller.client.robot import ARM_FOLLOW_S, WAIT_TIMEOUT_S, Robot
from controller.client.stream import LOW_WATER_S, StreamProgress

T = TypeVar("T")
R = TypeVar("R")
POSE_QUEUE = 1_000
"""The most pose samples an async pose iterator keeps unread (the oldest is dropped)."""


@dataclass(frozen=True)
class _Done(Generic[R]):
    """A blocking generator's end, with its return value."""

    value: R


class AsyncRobot:
    """A `Robot` driven from asyncio: the same methods, as coroutines. Make one with
    `await AsyncRobot.connect(...)` (or around a `Robot` of yours); use it as an async context
    manager. `robot` is the threaded Robot underneath (its non-blocking methods, `setpoint`
    and `velocity`, are offered here as plain methods)."""

    def __init__(self, robot: Robot) -> None:
        self.robot = robot

    @classmethod
    async def connect(
        cls,
        endpoint: str | None = None,
        prefix: str | None = None,
        *,
        zenoh_config: str | None = None,
        timeout_s: float = transport.DEFAULT_TIMEOUT_S,
    ) -> AsyncRobot:
        """Open a `Robot` (in a worker thread). Raises as `Robot` does."""
        robot = await asyncio.to_thread(
            Robot, endpoint, prefix, zenoh_config=zenoh_config, timeout_s=timeout_s
        )
        return cls(robot)

    async def __aenter__(self) -> AsyncRobot:
        return self

    async def __aexit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        try:
            if exc is not None:
                await asyncio.to_thread(self.robot.brake_if_moving, exc)
        finally:
            await self.aclose()

    async def aclose(self) -> None:
        """Close the Robot (its session, unless it was given one)."""
        await asyncio.to_thread(self.robot.close)

    async def _call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        return await asyncio.to_thread(fn, *args, **kwargs)

    # ------------------------------------------------------------------------------ reading
    async def status(self) -> Status:
        """`Robot.status`."""
        return await self._call(self.robot.status)

    async def pose(self, *, max_age_s: float = 0.5, timeout_s: float | None = None) -> Pose:
        """`Robot.pose`."""
        return await self._call(self.robot.pose, max_age_s=max_age_s, timeout_s=timeout_s)

    async def truth(self, timeout_s: float = 1.0) -> Truth | None:
        """`Robot.truth`."""
        return await self._call(self.robot.truth, timeout_s)

    async def poses(self, *, timeout_s: float | None = None) -> AsyncGenerator[Pose, None]:
        """Every pose sample from now on, as an async iterator (`Robot.poses`); raises
        DaemonAbsent when none arrives for `timeout_s` (default: the Robot's). At most
        `POSE_QUEUE` wait unread; the oldest is dropped."""
        loop = asyncio.get_running_loop()
        q: asyncio.Queue[Pose] = asyncio.Queue()
        wait_s = self.robot.timeout_s if timeout_s is None else timeout_s

        def put(pose: Pose) -> None:  # on the loop
            if q.qsize() >= POSE_QUEUE:
                q.get_nowait()
            q.put_nowait(pose)

        def on_pose(pose: Pose) -> None:  # on Zenoh's thread
            loop.call_soon_threadsafe(put, pose)

        sub = self.robot.on_pose(on_pose)
        try:
            while True:
                try:
                    pose = await asyncio.wait_for(q.get(), wait_s)
                except TimeoutError:
                    raise DaemonAbsent(f"no pose sample within {wait_s:g} s") from None
                yield pose
        finally:
            sub.close()

    # ---------------------------------------------------------------------------- commanding
    async def command(self, verb: str, payload: dict[str, Any] | None = None) -> Reply:
        """`Robot.command`."""
        return await self._call(self.robot.command, verb, payload)

    async def move(self, position_m: Sequence[float], *, speed_mps: float | None = None) -> Reply:
        """`Robot.move`."""
        return await self._call(self.robot.move, position_m, speed_mps=speed_mps)

    async def path(
        self,
        points_m: Iterable[Sequence[float]],
        *,
        speed_mps: float | None = None,
        append: bool = False,
    ) -> Reply:
        """`Robot.path`."""
        pts = list(points_m)
        return await self._call(self.robot.path, pts, speed_mps=speed_mps, append=append)

    async def stop(self) -> Reply:
        """`Robot.stop`."""
        return await self._call(self.robot.stop)

    async def estop(self) -> Reply:
        """`Robot.estop`."""
        return await self._call(self.robot.estop)

    async def arm(self) -> Reply:
        """`Robot.arm`."""
        return await self._call(self.robot.arm)

    async def disarm(self) -> Reply:
        """`Robot.disarm`."""
        return await self._call(self.robot.disarm)

    async def reset(self) -> Reply:
        """`Robot.reset`."""
        return await self._call(self.robot.reset)

    async def home(self, position_m: Sequence[float]) -> Reply:
        """`Robot.home`."""
        return await self._call(self.robot.home, position_m)

    async def pretension(self, position_m: Sequence[float]) -> Reply:
        """`Robot.pretension`."""
        return await self._call(self.robot.pretension, position_m)

    def setpoint(self, position_m: Sequence[float]) -> None:
        """`Robot.setpoint` (a put that never waits)."""
        self.robot.setpoint(position_m)

    def velocity(self, velocity_mps: Sequence[float]) -> None:
        """`Robot.velocity` (a put that never waits)."""
        self.robot.velocity(velocity_mps)

    # ---------------------------------------------------------------------------- following
    async def wait(
        self,
        timeout_s: float = WAIT_TIMEOUT_S,
        *,
        on_progress: Callable[[ArrivalProgress], None] | None = None,
        brake: bool = True,
    ) -> Pose:
        """`Robot.wait`; `on_progress` is called on the event loop. Cancelling the task brakes
        the robot to a hold (with `brake`) before the cancellation goes on."""
        loop = asyncio.get_running_loop()
        cancel = threading.Event()
        progress = None
        if on_progress is not None:
            cb = on_progress

            def progress(p: ArrivalProgress) -> None:
                loop.call_soon_threadsafe(cb, p)

        task = asyncio.ensure_future(
            asyncio.to_thread(
                self.robot.wait, timeout_s, on_progress=progress, brake=brake, cancel=cancel
            )
        )
        try:
            return await asyncio.shield(task)
        except asyncio.CancelledError:
            cancel.set()  # the worker brakes and ends
            with suppress(BaseException):
                await task
            raise

    async def wait_armed(self, timeout_s: float = ARM_FOLLOW_S) -> Status:
        """`Robot.wait_armed`."""
        return await self._call(self.robot.wait_armed, timeout_s)

    async def wait_pretension(self, timeout_s: float = WAIT_TIMEOUT_S) -> PretensionResult:
        """`Robot.wait_pretension`."""
        return await self._call(self.robot.wait_pretension, timeout_s)

    async def iter_path(
        self,
        points_m: Iterable[Sequence[float]],
        *,
        speed_mps: float | None = None,
        append: bool = False,
        brake: bool = True,
        low_water_s: float = LOW_WATER_S,
    ) -> AsyncGenerator[StreamProgress, None]:
        """`Robot.iter_path` as an async iterator (close it with `contextlib.aclosing`, or let
        it end). Cancelling, or closing it early, brakes the robot to a hold (with `brake`)."""
        # The whole path is checked first (queries): off the event loop, as every call.
        steps = await asyncio.to_thread(
            self.robot.iter_path,
            list(points_m),
            speed_mps=speed_mps,
            append=append,
            brake=brake,
            low_water_s=low_water_s,
        )
        try:
            while True:
                item = await _step(steps)
                if isinstance(item, _Done):
                    return
                yield item
        finally:
            await asyncio.to_thread(steps.close)  # brakes unless the stream ended

    async def load_gcode(self, file: str) -> GcodeJob:
        """`controller.client.job.load_gcode` on this robot."""
        return await self._call(load_gcode, self.robot, file)

    async def iter_job(
        self,
        job: GcodeJob,
        *,
        wait: bool = False,
        wait_timeout_s: float = math.inf,
        brake: bool = True,
    ) -> AsyncGenerator[JobProgress, None]:
        """`controller.client.job.iter_job` as an async iterator. Cancelling, or closing it
        early, brakes the robot to a hold (with `brake`)."""
        steps = iter_job(self.robot, job, wait=wait, wait_timeout_s=wait_timeout_s, brake=brake)
        try:
            while True:
                item = await _step(steps)
                if isinstance(item, _Done):
                    return
                yield item
        finally:
            await asyncio.to_thread(steps.close)  # brakes unless the job ended

    async def run_job(
        self,
        job: GcodeJob,
        *,
        wait: bool = False,
        wait_timeout_s: float = math.inf,
        on_progress: Callable[[JobProgress], None] | None = None,
        brake: bool = True,
    ) -> JobResult:
        """`controller.client.job.run_job`; `on_progress` is called on the event loop.
        Cancelling brakes the robot to a hold (with `brake`)."""
        steps = iter_job(self.robot, job, wait=wait, wait_timeout_s=wait_timeout_s, brake=brake)
        try:
            while True:
                item = await _step(steps)
                if isinstance(item, _Done):
                    result: JobResult = item.value
                    return result
                if on_progress is not None:
                    on_progress(item)
        finally:
            await asyncio.to_thread(steps.close)

    async def stream_path(
        self,
        points_m: Iterable[Sequence[float]],
        *,
        speed_mps: float | None = None,
        append: bool = False,
        on_progress: Callable[[StreamProgress], None] | None = None,
        brake: bool = True,
        low_water_s: float = LOW_WATER_S,
    ) -> StreamProgress:
        """`Robot.stream_path`; `on_progress` is called on the event loop."""
        last = StreamProgress(total=0)
        steps = self.iter_path(
            points_m, speed_mps=speed_mps, append=append, brake=brake, low_water_s=low_water_s
        )
        try:
            async for last in steps:
                if on_progress is not None:
                    on_progress(last)
        finally:
            await steps.aclose()
        return last


async def _step(steps: Generator[T, None, R]) -> T | _Done[R]:
    """The next item of a blocking generator, from a worker thread (`_Done` with its return
    value at its end). A cancellation waits for the step in flight: the generator may be
    closed only between steps."""

    def step() -> T | _Done[R]:
        try:
            return next(steps)
        except StopIteration as stop:
            return _Done(stop.value)

    task = asyncio.ensure_future(asyncio.to_thread(step))
    try:
        return await asyncio.shield(task)
    except asyncio.CancelledError:
        with suppress(BaseException):
            await task
        raise
