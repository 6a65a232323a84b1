"""The effector's vibration after a move, measured on the simulated physical plant through the
real control step: the figures of docs/shaping.md (`tools/shaping_figures.py` runs them all)
and the benchmark's shaping section.

`PlantRig` is a `Controller` ticked on a hand-moved clock against `PlantDriver`, whose reels
are ideal drives (each motor is at the turns last commanded) carrying the payload on the
elastic cables of `controller.core.plant.ReelPlant`, stepped once per tick: no bus, no
threads, deterministic. The plant's position is the truth. A rest-to-rest move is flown from
the plant at rest; its end is the tick the controller is back in HOLDING (the shaped set-point
has arrived); the residual vibration is the largest distance of the truth from where the
commanded lengths bring the effector to rest (the target when the model is exact; taken at the
end of the watch, when drives with a position loop have caught up) over the `settle_s` after
that end.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

Vec3 = tuple[float, float, float]

SETTLE_S = 3.0
"""How long after the end of a move its residual vibration is watched."""
PAPER_EA_N = 4.5e5
"""The paper robot's cables in the figures: EA 4.5e5 N (a 6 mm steel rope's order)."""
DESK_EA_N = 1e5
"""The desk rig's braided line."""
PLANT_DAMPING_RATIO = 0.02
"""The simulated ropes' damping ratio in the figures."""
DRAG_PER_S = 0.1
"""The simulated effector's light drag, per kilogram (N s/m)/kg."""


class _Clock:
    """A monotonic clock moved by hand."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s

    def wall_ns(self) -> int:
        """The same time as a wall clock in ns."""
        return int(self.now_s * 1e9)


class PlantDriver:
    """A `drivers.base.ReelDriver` whose reels carry a `ReelPlant` (the plant stepped by
    `step`; each axis reports the torque its cable needs, as torque telemetry) and follow the
    commanded turns: ideal drives (each axis at the turns last commanded, in closed loop after
    `arm`), or with `drive` = (position gain (rev/s)/rev, velocity limit rev/s, acceleration
    limit rev/s^2) the simulated ODrive's cascaded loop (`drivers.odrive.sim`: velocity =
    feed-forward + gain x error, limited, in 1 ms sub-steps). No bus, no frames."""

    def __init__(
        self,
        node_ids: Sequence[int],
        plant: Any,
        clock: _Clock,
        drive: tuple[float, float, float] | None = None,
    ) -> None:
        from drivers.base import AxisReading, BusStats

        self.node_ids = tuple(node_ids)
        self.plant = plant
        self._clock = clock
        self._drive = drive
        self._turns = list(plant.positions_rev)
        self._pos = list(self._turns)
        self._vel = [0.0] * len(self._turns)
        self._ff = [0.0] * len(self._turns)
        self._readings = [
            AxisReading(nid, position_rev=float(p), axis_state=1, state_name="IDLE")
            for nid, p in zip(self.node_ids, self._turns, strict=True)
        ]
        self._stats = BusStats()
        self._armed = False

    def step(self, dt_s: float) -> None:
        """Step the plant `dt_s` with the reels moving to the turns last commanded (at once,
        or through the drive's loop)."""
        if self._drive is None:
            self.plant.step(self._turns, dt_s)
            return
        gain, vmax, amax = self._drive
        n = max(1, math.ceil(dt_s / 0.001))
        h = dt_s / n
        pos, vel, ff, cmd = self._pos, self._vel, self._ff, self._turns
        for _ in range(n):
            for i in range(len(pos)):
                want = max(-vmax, min(vmax, ff[i] + gain * (cmd[i] - pos[i])))
                v2 = vel[i] + max(-amax * h, min(amax * h, want - vel[i]))
                pos[i] += 0.5 * (vel[i] + v2) * h
                vel[i] = v2
            self.plant.step(pos, h)

    def poll(self) -> int:
        """Every reading fresh at the clock's time, each axis at its commanded turns."""
        now = self._clock.now_s
        now_ns = int(now * 1e9)
        torques = self.plant.torques_nm
        at = self._turns if self._drive is None else self._pos
        for i, r in enumerate(self._readings):
            r.position_rev = at[i]
            r.stamp_s = now
            r.stamp_ns = now_ns
            r.heartbeat_stamp_s = now
            r.status_stamp_s = now
            r.torque_nm = torques[i]
            r.torque_stamp_s = now
        return len(self._readings)

    def read(self) -> Sequence[Any]:
        """The readings, in the order of `node_ids`."""
        return self._readings

    def command(
        self, positions_rev: Sequence[float], velocity_ff_rps: Sequence[float] | None = None
    ) -> None:
        """The reels go to `positions_rev` over the next step; ValueError for a non-finite
        value or a wrong count."""
        if len(positions_rev) != len(self.node_ids):
            raise ValueError(f"{len(positions_rev)} set-points for {len(self.node_ids)} axes")
        if not all(math.isfinite(v) for v in positions_rev):
            raise ValueError(f"non-finite set-point {list(positions_rev)}")
        if self._armed:
            self._turns = [float(v) for v in positions_rev]
            if velocity_ff_rps is not None:
                self._ff = [float(v) for v in velocity_ff_rps]

    def arm(self) -> None:
        """Every axis enters closed loop at once."""
        now = self._clock.now_s
        self._armed = True
        for r in self._readings:
            r.axis_state = 8
            r.ready = True
            r.fault = None
            r.state_name = "CLOSED_LOOP_CONTROL"
            r.command_stamp_s = now

    def disarm(self) -> None:
        """Every axis goes idle (the reels stay where they are)."""
        self._armed = False
        for r in self._readings:
            r.axis_state = 1
            r.ready = False
            r.state_name = "IDLE"

    def estop(self) -> None:
        """As `disarm`."""
        self.disarm()

    def request_encoders(self) -> None:
        """Nothing to ask."""

    @property
    def stats(self) -> Any:
        """The traffic counters (all zero: no bus)."""
        return self._stats


@dataclass(frozen=True, slots=True)
class MoveResult:
    """One rest-to-rest move on the plant: when it ended (s after the command), the residual
    vibration (m, over `SETTLE_S`), where the truth came to rest against the target (m), the
    shaper's delay at the end (s) and the set-point's largest distance from the straight
    line (m)."""

    duration_s: float
    residual_m: float
    rest_offset_m: float
    shaper_delay_s: float
    off_line_m: float


def robot_data(name: str) -> dict[str, Any]:
    """The TOML data of a robot of the figures: "paper" (the built-in robot) or "desk"
    (`config/desk.toml` on a virtual bus). Raises ValueError for another name."""
    import copy
    import tomllib

    from controller.cli.configs import find_example
    from controller.service.config import paper_robot_data

    if name == "paper":
        return paper_robot_data("vibration")
    if name == "desk":
        with find_example("desk").open("rb") as f:
            data = tomllib.load(f)
        data = copy.deepcopy(data)
        data["bus"] = {"interface": "virtual", "channel": "vibration"}
        return data
    raise ValueError(f"unknown robot {name!r} (paper, desk)")


def robot_config(
    data: dict[str, Any],
    *,
    mass_kg: float,
    plant_ea_n: float,
    model_ea_n: float,
    start_m: Vec3,
    shaper: dict[str, Any] | None,
    max_tension_n: float | None = None,
    telemetry: str = "off",
) -> Any:
    """The robot of TOML `data` carrying `mass_kg` from `start_m`, its reels modelled with EA
    `model_ea_n`, the simulated plant's cables of `plant_ea_n` with realistic ropes
    (`PLANT_DAMPING_RATIO`) and a light drag, the `[shaper]` keys `shaper` (None: off),
    generous faults (a measurement, not a fault test), `max_tension_n` if given and the torque
    `telemetry` ("off", "cyclic"). Raises ConfigError."""
    import copy

    from controller.service.config import parse_config

    d = copy.deepcopy(data)
    for r in d["reels"]:
        r["cable_ea_n"] = model_ea_n
    d["payload"] = {"mass_kg": mass_kg}
    if max_tension_n is not None:
        d["limits"]["max_tension_n"] = max_tension_n
    d["faults"] = {
        **d.get("faults", {}),
        "tracking_max_m": 10.0,
        "residual_max_m": 1.0,
        "stale_timeout_s": 1.0,
    }
    d["homing"] = {"power_up_position_m": list(start_m)}
    d["sim"] = {
        "enabled": False,
        "plant": "physical",
        "cable_ea_n": plant_ea_n,
        "cable_damping_ratio": PLANT_DAMPING_RATIO,
        "effector_damping_n_s_per_m": DRAG_PER_S * mass_kg,
    }
    d["shaper"] = {"type": "off"} if shaper is None else dict(shaper)
    d["loop"] = {**d.get("loop", {}), "torque_telemetry": telemetry}
    return parse_config(d, f"<vibration {d.get('name', 'robot')}>")


class PlantRig:
    """The controller of `cfg` on a `PlantDriver` carrying `cfg`'s physical plant, homed at
    its power-up pose with the plant at rest there, armed; ideal drives, or with
    `odrive_loop` the simulated ODrive's position loop (its gain, `[sim]`'s limits). Every
    tick lasts the loop's period, or with `jitter` a fraction up to that much longer or
    shorter at random (uniform, seeded by `seed`: repeatable). Raises RuntimeError if it does
    not arm."""

    def __init__(
        self,
        cfg: Any,
        publisher: Any = None,
        *,
        odrive_loop: bool = False,
        jitter: float = 0.0,
        seed: int = 1,
    ) -> None:
        from controller.core import kinematics
        from controller.core.commands import Arm
        from controller.core.states import State
        from controller.service.loop import Controller
        from controller.service.simulated import sim_plant
        from drivers.odrive.sim import DEFAULT_POS_GAIN

        self.cfg = cfg
        pose = cfg.homing.power_up_position_m
        lengths = kinematics.ipk_point(cfg.geometry, pose)
        turns = [r.reel.position_rev(L) for r, L in zip(cfg.reels, lengths, strict=True)]
        self.plant = sim_plant(cfg, turns)
        self.clock = _Clock()
        drive = (
            (DEFAULT_POS_GAIN, float(cfg.sim.max_velocity_rps), float(cfg.sim.max_accel_rps2))
            if odrive_loop
            else None
        )
        self.driver = PlantDriver([r.node_id for r in cfg.reels], self.plant, self.clock, drive)
        self.ctl = Controller(
            cfg, self.driver, publisher, clock=self.clock, wall_clock_ns=self.clock.wall_ns
        )
        self.period_s = 1.0 / float(cfg.loop.rate_hz)
        self._jitter = jitter
        self._rng = random.Random(seed)
        self.tick(2)
        self.ctl.submit(Arm())
        for _ in range(1000):
            self.tick(1)
            if self.ctl.state is State.HOLDING:
                break
        if self.ctl.state is not State.HOLDING:
            raise RuntimeError(f"not armed: {self.ctl.state.value} {self.ctl.reason}")

    def tick(self, n: int) -> None:
        """`n` ticks: the controller's step, then the plant's."""
        dt = self.period_s
        for _ in range(n):
            if self._jitter:
                dt = self.period_s * (1.0 + self._jitter * self._rng.uniform(-1.0, 1.0))
            self.clock.now_s += dt
            self.ctl.tick(self.clock.now_s)
            self.driver.step(dt)

    def rest_point_m(self) -> Vec3:
        """Where the effector comes to rest on the lengths commanded now."""
        from controller.core.plant import equilibrium

        plant = self.plant.plant
        eq = equilibrium(plant.params, plant.unstretched_m, plant.position_m)
        return eq.position_m

    def move(self, target_m: Vec3, speed_mps: float, settle_s: float = SETTLE_S) -> MoveResult:
        """Fly a straight move to `target_m` at `speed_mps` and watch the truth for
        `settle_s` after it ends. Raises RuntimeError if the move is refused or faults."""
        from controller.core.commands import Move
        from controller.core.states import State

        ctl = self.ctl
        start = ctl.setpoint_m
        assert start is not None
        fut = ctl.submit(Move(target_m, speed_mps))
        self.tick(1)
        exc = fut.exception(timeout=0) if fut.done() else None
        if exc is not None:
            raise RuntimeError(f"move refused: {exc}")
        t0 = self.clock.now_s
        off_line = 0.0
        span = math.dist(start, target_m)
        limit = 120.0 / self.period_s
        n = 0
        while ctl.state is State.MOVING:
            self.tick(1)
            off_line = max(off_line, _off_line(ctl.setpoint_m, start, target_m, span))
            n += 1
            if n > limit:
                raise RuntimeError("the move did not end in 120 s")
        if ctl.state is not State.HOLDING:
            raise RuntimeError(f"the move ended in {ctl.state.value}: {ctl.reason}")
        duration = self.clock.now_s - t0
        delay = ctl.shaping.shaper.duration_s if ctl.shaping.shaper is not None else 0.0
        path = []
        for _ in range(round(settle_s / self.period_s)):
            self.tick(1)
            path.append(self.plant.position_m)
        rest = self.rest_point_m()  # the drives have caught up with the last commands by now
        peak = max(math.dist(p, rest) for p in path)
        return MoveResult(duration, peak, math.dist(rest, target_m), delay, off_line)


def _off_line(p: Sequence[float] | None, a: Vec3, b: Vec3, span: float) -> float:
    """Distance of `p` from the straight line through `a` and `b` (span = |b - a| > 0)."""
    if p is None or span <= 0.0:
        return 0.0
    d = [b[i] - a[i] for i in range(3)]
    w = [p[i] - a[i] for i in range(3)]
    t = sum(d[i] * w[i] for i in range(3)) / (span * span)
    return math.dist(p, tuple(a[i] + t * d[i] for i in range(3)))


class RecordingPublisher:
    """A `controller.service.pose.Publisher` keeping every pose sample as its JSON object."""

    def __init__(self) -> None:
        self.samples: list[dict[str, Any]] = []

    def publish_pose(self, sample: Any) -> None:
        """Keep the sample (decoded from its JSON)."""
        import json

        self.samples.append(json.loads(sample.to_json_bytes()))

    def publish_state(self, state: str, reason: str | None, stamp_ns: int) -> None:
        """Nothing to keep."""


class RigLink:
    """`controller.cli.resonance.Link` over a `PlantRig` built with a `RecordingPublisher`:
    commands parsed as the Zenoh interface parses them and taken by the next ticks, the pose
    samples the rig published, time passing as ticks."""

    def __init__(self, rig: PlantRig, poses: RecordingPublisher) -> None:
        self.rig = rig
        self.poses = poses

    def status(self) -> dict[str, Any]:
        """The controller's status."""
        status: dict[str, Any] = self.rig.ctl.status()
        return status

    def command(self, verb: str, payload: dict[str, Any] | None) -> dict[str, Any]:
        """Submit the command, tick until answered; raises Refused with its reason."""
        import json

        from controller.cli.session import Refused
        from controller.core.commands import CommandError, parse_command

        try:
            cmd = parse_command(verb, None if payload is None else json.dumps(payload))
        except CommandError as exc:
            raise Refused(str(exc)) from None
        fut = self.rig.ctl.submit(cmd)
        for _ in range(100):
            self.rig.tick(1)
            if fut.done():
                break
        failure = fut.exception(timeout=0)
        if failure is not None:
            raise Refused(str(failure))
        reply: dict[str, Any] = fut.result(timeout=0)
        return reply

    def take_samples(self) -> list[dict[str, Any]]:
        """The samples published since the last call."""
        out = self.poses.samples
        self.poses.samples = []
        return out

    def pause(self, seconds: float) -> None:
        """`seconds` of ticks."""
        self.rig.tick(max(1, round(seconds / self.rig.period_s)))
