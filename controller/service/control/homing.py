"""Homing and the pre-tension before it: the `home` command, the homing save off the loop thread,
and the pre-tension run (torque control until the reels are still, then home there).
"""

from __future__ import annotations

import concurrent.futures
import math
import threading
import time
from collections.abc import Sequence
from typing import Any

from controller.core.commands import CommandRefused, Home, Pretension, Vec3
from controller.core.pretension import PretensionRun
from controller.core.states import State
from controller.service.control.base import _Fault, _fmt, log
from controller.service.control.faults import FaultHandling
from drivers.base import AxisReading, BusError, TorqueDriver


class Homing(FaultHandling):
    """Homing, its save, and the pre-tension of the controller."""

    # ---------------------------------------------------------------- homing

    def _refuse_stale(self, readings: Sequence[AxisReading], now_s: float) -> None:
        """CommandRefused naming every axis without a fresh encoder reading (homing needs
        them all)."""
        old = [r for r in readings if now_s - r.stamp_s > self._stale_s]
        if old:
            ages = ", ".join(
                f"node {r.node_id} "
                + (f"{now_s - r.stamp_s:.3f} s old" if math.isfinite(r.stamp_s) else "never heard")
                for r in old
            )
            raise CommandRefused(
                f"stale_encoder: no fresh encoder reading ({ages}; faults.stale_timeout_s is "
                f"{self._stale_s:g} s): check the drive's encoder broadcast rate, or raise "
                "faults.stale_timeout_s"
            )

    def _execute_home(
        self, cmd: Home, readings: Sequence[AxisReading], now_s: float
    ) -> dict[str, Any] | concurrent.futures.Future[dict[str, Any]]:
        self._refuse_stale(readings, now_s)
        reason = self._check_target(cmd.position_m)
        if reason is not None:
            raise CommandRefused(f"home position {_fmt(cmd.position_m)}: {reason}")
        offsets = self._home_at(readings, cmd.position_m)
        self.home_source = "home"
        if self.state is State.HOLDING:
            # Keep the motors where they are: the same turns now mean the home pose.
            self._hold_at(cmd.position_m)
            self.setpoint_lengths_m = None
        log.info("homed at %s: offsets_rev %s", _fmt(cmd.position_m), offsets)
        reply: dict[str, Any] = {
            "ok": True,
            "position_m": list(cmd.position_m),
            "offsets_rev": dict(zip(map(str, self.node_ids), offsets, strict=True)),
            "saved": False,
        }
        saved = self._save_home(offsets, cmd.position_m, reply)
        return reply if saved is None else saved

    def _save_home(
        self, offsets: Sequence[float], position_m: Vec3, reply: dict[str, Any]
    ) -> concurrent.futures.Future[dict[str, Any]] | None:
        """Save the homing offsets to the state file off the loop thread: a future of `reply`
        with "saved" (and "state_file" or "error"), or None without a state file."""
        if not self._state_file:
            return None
        from controller.service import offsets as homing

        state = homing.make_record(
            self.cfg.name, dict(zip(self.node_ids, offsets, strict=True)), position_m
        )
        path = self._state_file
        # fsync can take tens of ms: save off the loop thread and answer when it is on disk.
        outer: concurrent.futures.Future[dict[str, Any]] = concurrent.futures.Future()

        def save() -> None:
            try:
                homing.save_offsets(path, state)
            except Exception as exc:
                log.error("saving homing offsets to %s failed: %s", path, exc)
                outer.set_result({**reply, "saved": False, "error": str(exc)})
            else:
                log.info("homing offsets saved to %s", path)
                outer.set_result({**reply, "saved": True, "state_file": path})

        t = threading.Thread(target=save, name="cablebot-home-save", daemon=True)
        self._save_threads = [th for th in self._save_threads if th.is_alive()] + [t]
        t.start()
        return outer

    def wait_for_saves(self, timeout_s: float = 2.0) -> None:
        """Wait (bounded) for homing saves in flight, e.g. before exiting."""
        deadline = time.monotonic() + timeout_s
        for t in list(self._save_threads):
            t.join(max(0.0, deadline - time.monotonic()))

    # ---------------------------------------------------------------- pre-tension

    def _start_pretension(
        self, cmd: Pretension, readings: Sequence[AxisReading], now_s: float
    ) -> dict[str, Any]:
        """Start the pre-tension at `cmd.position_m` (`controller.core.pretension`): torque
        control on every reel, each pulling with its cable's statics tension at that pose.
        Raises CommandRefused (nothing sent) when the drive family has no torque control, there
        is no `[payload]`, an encoder reading is stale, the pose breaks a limit or a reel's
        slope is zero; CommandRefused naming the bus when entering torque control fails."""
        drv = self.driver
        if not isinstance(drv, TorqueDriver):
            raise CommandRefused(
                f"pretension: cablebot has no torque control for {self.cfg.drive.kind} drives; "
                "home without --pretension"
            )
        chk = self.tension
        if chk is None:
            raise CommandRefused(
                "pretension: needs [payload] mass_kg (the reels pull with the tensions that hold "
                "the payload at the home pose)"
            )
        if self.cfg.kinematic_sim:
            where = "in the daemon" if self.cfg.sim.enabled else "by `cablebot sim`"
            raise CommandRefused(
                "pretension: the reels are the kinematic simulator's (simulated drives on "
                f"{self.cfg.bus.interface} {self.cfg.bus.channel}, run {where}, [sim] plant = "
                '"kinematic"): it carries no load, so they would wind in and never come still; '
                'give the robot file [sim] plant = "physical" (and run `cablebot sim` with it)'
            )
        self._refuse_stale(readings, now_s)
        p = cmd.position_m
        reason = self._check_target(p)
        if reason is not None:
            raise CommandRefused(f"home position {_fmt(p)}: {reason}")
        tensions = chk.solve(p).tensions_n
        settings = self.cfg.homing.pretension
        reels = self.reels
        try:
            torques = [
                reels[i].torque_nm(r.position_rev, tensions[i]) for i, r in enumerate(readings)
            ]
            limits = [
                abs(reels[i].velocity_rps(r.position_rev, settings.speed_mps))
                for i, r in enumerate(readings)
            ]
            lengths = [reels[i].length_m(r.position_rev) for i, r in enumerate(readings)]
            run = PretensionRun(settings, tensions, lengths, now_s)
        except ValueError as exc:  # a reel slope of zero, a non-finite number
            raise CommandRefused(f"pretension: {exc}") from None
        try:
            limited = drv.enter_torque_mode(torques, limits)
        except (BusError, ValueError) as exc:
            raise CommandRefused(f"bus_error: pretension: {exc}") from None
        self._torque_driver = drv
        self._pretension = run
        self._pretension_at = p
        self.pretension_result = None
        self.commanded_rev = None
        self.commanded_ff_rps = list(self._zero_ff)
        self.setpoint_m = None
        self.setpoint_lengths_m = None
        self._stream_target = None
        self._velocity_cmd = None
        self._arm_epoch += 1  # set-points streamed before it are never taken after it
        speed = (
            f"at most {settings.speed_mps:g} m/s of cable"
            if limited
            else "as fast as the drives' own velocity limit lets them"
        )
        self._set_state(
            State.PRETENSIONING,
            f"pretension: the reels pull in torque control ({speed}) until still, then home "
            f"at {_fmt(p)}",
        )
        return {
            "ok": True,
            "state": State.PRETENSIONING.value,
            "position_m": list(p),
            "tensions_n": list(tensions),
            "torques_nm": torques,
            "speed_limited": limited,
        }

    def _tick_pretension(self, readings: Sequence[AxisReading], now_s: float) -> None:
        """One tick of the pre-tension: axis checks, travel and stillness (`PretensionRun`),
        then the torques of the tensions, or the home pose once the reels are still. _Fault on
        an axis fault, a stale reading, an axis not in closed loop after `faults.arm_timeout_s`,
        or the run failing."""
        run = self._pretension
        assert run is not None
        ready = self._check_axes(readings, now_s, ready=False)
        if not ready and now_s - run.start_s > self._arm_timeout_s:
            r = next(r for r in readings if not (r.ready and r.status_fresh()))
            raise _Fault(
                f"pretension: node {r.node_id} not in closed loop after "
                f"{self._arm_timeout_s:g} s ({r.state_name}"
                f"{'' if r.status_fresh() else ', no answer since the command'})"
            )
        if ready:
            reels = self.reels
            lengths = self._pt_lengths_m
            rates = self._pt_rates_mps
            for i, r in enumerate(readings):
                lengths[i] = reels[i].length_m(r.position_rev)
                rates[i] = reels[i].length_rate_mps(r.position_rev, r.velocity_rps)
            why = run.update(now_s, lengths, rates)
            if why is not None:
                raise _Fault(f"pretension: {why}")
            if run.done:
                self._finish_pretension(readings, run)
                return
        drv = self._torque_driver
        assert drv is not None  # set with the run
        # The tensions through the reel model at this tick's turns: a spool that builds up
        # keeps pulling the tension, not the torque, of the start.
        torques = self._pt_torques_nm
        reels = self.reels
        tensions = run.tensions_n
        for i, r in enumerate(readings):
            torques[i] = reels[i].torque_nm(r.position_rev, tensions[i])
        try:
            drv.command_torque(torques)
        except BusError:
            pass  # counted in driver.stats.bus_errors; the next tick faults if they persist
        except ValueError as exc:
            raise _Fault(f"nan_setpoint: driver refused a torque: {exc}") from None

    def _finish_pretension(self, readings: Sequence[AxisReading], run: PretensionRun) -> None:
        """The reels are still: hold their turns in position control, declare the home pose
        there, save the offsets, and go HOLDING. _Fault if the pose cannot be held."""
        p = self._pretension_at
        self._end_pretension()
        offsets = self._home_at(readings, p)
        self.home_source = "pretension"
        measured = list(self.measured_tensions_n) if self._measure else None
        after = run.still_after_s if run.still_after_s is not None else 0.0
        log.info(
            "pretension: still after %.2f s; homed at %s: offsets_rev %s", after, _fmt(p), offsets
        )
        result: dict[str, Any] = {
            "ok": True,
            "position_m": list(p),
            "still_after_s": after,
            "tensions_n": list(run.tensions_n),
            "measured_tensions_n": measured,
            "offsets_rev": dict(zip(map(str, self.node_ids), offsets, strict=True)),
            "saved": False,
        }
        saved = self._save_home(offsets, p, result)
        if saved is None:
            self.pretension_result = result
        else:
            # the offsets go to disk off the loop thread: until they are there the result says
            # so (a client waiting for the pre-tension waits for the save's outcome too)
            self.pretension_result = {**result, "saving": True, "state_file": self._state_file}

            def record(fut: concurrent.futures.Future[dict[str, Any]]) -> None:
                self.pretension_result = fut.result()  # one reference assignment: atomic

            saved.add_done_callback(record)
        self._set_state(State.HOLDING, f"pretension: still after {after:.2f} s, homed")
        self._hold_at(p)
        self.setpoint_lengths_m = None

    def _end_pretension(self) -> list[float] | None:
        """Leave torque control if a pre-tension is running: every drive holds the turns its
        reel is at (they become the commanded turns, as in FAULT) and gets its velocity limit
        back. Returns those turns, or None when no pre-tension was running. Never raises."""
        if self._pretension is None:
            return None
        self._pretension = None
        positions = [r.position_rev for r in self.driver.read()]
        drv = self._torque_driver
        try:
            assert drv is not None  # set with the run
            drv.leave_torque_mode(positions)
        except Exception as exc:  # the hold is re-sent every tick in FAULT
            log.error("pretension: leaving torque control failed: %s", exc)
        self.commanded_rev = positions
        self.commanded_ff_rps = list(self._zero_ff)
        return positions

    def _stop_pretension(self) -> None:
        """`stop` while pretensioning: the drives hold where the reels are; HOLDING at the
        measured pose when it is known, else FAULT (nothing to hold the pose by)."""
        self._end_pretension()
        self.pretension_result = {"ok": False, "reason": "stopped"}
        pose = self.pose_m
        if self.homed and self.pose_valid and pose is not None:
            self._set_state(State.HOLDING, "pretension stopped: holding where the reels are")
            try:
                self._hold_at(pose)
            except _Fault as f:
                self._fault(f.reason)
        else:
            self._fault(
                "pretension stopped before the reels were still, with no known pose: the motors "
                "hold their turns; reset, then home"
            )
