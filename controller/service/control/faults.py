"""Fault detection and the safe states: state changes, the checks that fault an armed robot
(axes, bus errors, torque telemetry), the FAULT hold, the e-stop and its confirmation, disarm.
"""

from __future__ import annotations

from collections.abc import Sequence

from controller.core.states import ARMED_STATES, State, check_transition
from controller.service.control.base import ESTOP_CONFIRM_S, ControllerState, _Fault, log
from drivers.base import AxisReading


class FaultHandling(ControllerState):
    """State changes, fault detection, FAULT hold, e-stop and disarm of the controller."""

    # ---------------------------------------------------------------- state changes

    def _set_state(self, new: State, reason: str | None = None) -> None:
        if new is self.state:
            return
        check_transition(self.state, new)
        old = self.state
        stamp_ns = self._wall_ns()
        if new is State.FAULT or new is State.ESTOPPED:
            log.error("state %s -> %s: %s", old.value, new.value, reason)
        else:
            log.info("state %s -> %s%s", old.value, new.value, f": {reason}" if reason else "")
        self._publish_state(new, reason, stamp_ns)
        # Recorded once published: whoever reads `state` and `reason` (another thread, the
        # status query) finds them already on the state key, never ahead of it.
        self.state = new
        self.reason = reason
        self.state_stamp_ns = stamp_ns

    def _set_reason(self, reason: str) -> None:
        """Change the reason of the current state and publish it (same state, new reason);
        `reason` is recorded once published, as in a state change."""
        log.error("state %s: %s", self.state.value, reason)
        self._publish_state(self.state, reason, self._wall_ns())
        self.reason = reason

    def _publish_state(self, state: State, reason: str | None, stamp_ns: int) -> None:
        try:
            self.publisher.publish_state(state.value, reason, stamp_ns)
        except Exception:
            log.exception("publish_state failed")

    def _fault(self, reason: str) -> None:
        """Enter FAULT (from an armed, arming or pretensioning state); the last good set-point
        stays commanded (after a pre-tension: the turns where the reels were)."""
        if self.state in (State.ARMING, State.HOLDING, State.MOVING, State.PRETENSIONING):
            if self._end_pretension() is not None:
                self.pretension_result = {"ok": False, "reason": reason}
            self._set_state(State.FAULT, reason)
            self.planner_hold()
            self.commanded_ff_rps = list(self._zero_ff)  # the hold has no feed-forward
            self._stream_target = None
            self._velocity_cmd = None

    def planner_hold(self) -> None:
        """Put the planner on hold at the last good set-point (no further motion)."""
        if self.setpoint_m is not None:
            self.planner.hold(self.setpoint_m)
            self.shaping.reset(self.setpoint_m)

    # ---------------------------------------------------------------- fault detection

    def _bus_errors_persist(self, now_s: float, state: State) -> None:
        """New bus errors this tick: fault (when armed or arming) once they have gone on for
        `faults.bus_error_timeout_s`. One lost frame at the loop rate is harmless (the ODrive
        keeps its last set-point), a bus-off or a dead link is not."""
        since = self._bus_err_since_s
        if since is None:
            self._bus_err_since_s = since = now_s
        if (state in ARMED_STATES or state is State.ARMING) and (
            now_s - since >= self._bus_err_timeout_s
        ):
            raise _Fault(
                f"bus_error: {self.driver.stats.last_error} (failing for {now_s - since:.3f} s)"
            )

    def _check_conflicts(self, now_s: float, state: State) -> None:
        """Another bus master was heard since the last tick (`BusStats.conflicts`, e.g. a second
        CiA 402 SYNC producer): _Fault `bus_conflict` naming it when armed, arming or
        pretensioning; remembered for the arm's refusal (`CONFLICT_HOLDOFF_S`)."""
        stats = self.driver.stats
        self._conflicts_seen = stats.conflicts
        self._conflict_s = now_s
        if state in ARMED_STATES or state is State.ARMING or state is State.PRETENSIONING:
            raise _Fault(f"bus_conflict: {stats.last_conflict}")

    def _check_axes(
        self, readings: Sequence[AxisReading], now_s: float, *, ready: bool = True
    ) -> bool:
        """Armed: every axis without a fault, fresh, and (with `ready`) ready (the drives'
        generic status); _Fault naming the first that is not. Returns whether every axis is
        ready."""
        stale = self._stale_s
        hb = self._hb_timeout_s
        all_ready = True
        for r in readings:
            fresh = r.status_stamp_s >= r.command_stamp_s  # the drive answered the last command
            if r.fault is not None and fresh:
                raise _Fault(f"axis_error: node {r.node_id} {r.fault}")
            if now_s - r.stamp_s > stale:
                raise _Fault(
                    f"stale_encoder: node {r.node_id} age {now_s - r.stamp_s:.3f} s > {stale:g} "
                    "s (on a busy machine raise [faults] stale_timeout_s)"
                )
            if now_s - r.heartbeat_stamp_s > hb:
                raise _Fault(
                    f"stale_heartbeat: node {r.node_id} age {now_s - r.heartbeat_stamp_s:.3f} s"
                )
            if not (r.ready and fresh):
                if ready and fresh:
                    raise _Fault(f"axis_state: node {r.node_id} left closed loop ({r.state_name})")
                all_ready = False
        return all_ready

    def _measure_tensions(
        self, readings: Sequence[AxisReading], now_s: float, state: State
    ) -> None:
        """Cable tensions from the torque telemetry (reel model, work balance); while HOLDING
        or MOVING, _Fault when one stays below `faults.slack_tension_n` or above the tension
        maximum for `faults.slack_time_s`, or when an axis's torque reading is stale."""
        armed = state is State.HOLDING or state is State.MOVING
        stale = self._stale_s
        reels = self.reels
        out = self.measured_tensions_n
        for i, r in enumerate(readings):
            age = now_s - r.torque_stamp_s
            t: float | None = None
            if age <= stale and r.ready:
                try:
                    t = reels[i].tension_n(r.position_rev, r.torque_nm)
                except ValueError:  # reel slope zero: no tension can be read
                    t = None
            out[i] = t
            if not armed:
                self._slack_since[i] = self._over_since[i] = None
                continue
            if t is None:
                if now_s - self._arm_start_s > stale and age > stale:
                    raise _Fault(f"stale_torque: node {r.node_id} age {age:.3f} s")
                continue
            slack = self._slack_n
            if slack is not None and t < slack:
                since = self._slack_since[i]
                if since is None:
                    self._slack_since[i] = since = now_s
                if now_s - since >= self._tension_time_s:
                    raise _Fault(f"slack: cable {i + 1} at {t:.3g} N")
            else:
                self._slack_since[i] = None
            over = self._over_n
            if over is not None and t > over:
                since = self._over_since[i]
                if since is None:
                    self._over_since[i] = since = now_s
                if now_s - since >= self._tension_time_s:
                    raise _Fault(f"over_tension: cable {i + 1} at {t:.4g} N > {over:.4g} N")
            else:
                self._over_since[i] = None

    # ------------------------------------------------------------ holding in FAULT and at shutdown

    def _hold_last(self) -> None:
        """In FAULT: keep sending the last good set-point, with zero velocity feed-forward, so
        the motors hold the load."""
        rev = self.commanded_rev
        if rev is None:
            return
        try:
            self.driver.command(rev, self._zero_ff)
        except Exception:  # already in FAULT; keep trying every tick
            self.hold_failures += 1

    def send_final_hold(self) -> bool:
        """Shutdown, after the loop thread has stopped: command the last set-point once more with
        zero velocity feed-forward, so the drives hold still on it instead of running on to
        `vel_ff / pos_gain` past it. Only while the motors are commanded (ARMING, HOLDING,
        MOVING, FAULT with a set-point). Returns True if it was sent; never raises.

        Call it only when the runner has returned: the loop thread is otherwise the driver's only
        user.
        """
        rev = self.commanded_rev
        commanded = (State.ARMING, State.HOLDING, State.MOVING, State.FAULT)
        if rev is None or self.state not in commanded:
            return False
        try:
            self.driver.command(rev, self._zero_ff)
        except Exception as exc:
            log.error("final hold not sent: %s", exc)
            return False
        self.commanded_ff_rps = list(self._zero_ff)
        return True

    # ---------------------------------------------------------------- e-stop and disarm

    def _do_estop(self, now_s: float) -> None:
        with self._estop_lock:
            futures = self._estop_futures
            self._estop_futures = []
            self._estop_flag = False
        err: str | None = None
        try:
            self.driver.estop()
        except Exception as exc:
            err = str(exc)
        if self._pretension is not None:
            self._end_pretension()  # after the Estop: restores the drives' velocity limits
            self.pretension_result = {"ok": False, "reason": "estop"}
        if self.state is not State.ESTOPPED:
            self._set_state(State.ESTOPPED, "estop" if err is None else f"estop (bus: {err})")
            self._estop_unconfirmed = ()
            self.estop_repeats = 0
        # Every e-stop (a repeated one too) restarts the confirmation from its own time.
        self._estop_at_s = now_s
        self._estop_check_s = now_s + ESTOP_CONFIRM_S
        self._estop_confirmed = False
        self.commanded_rev = None
        self.setpoint_m = None
        self.setpoint_lengths_m = None
        self._stream_target = None
        self._velocity_cmd = None
        for fut in futures:
            fut.set_result({"ok": True, "state": self.state.value})

    def _confirm_estop(self, readings: Sequence[AxisReading], now_s: float) -> None:
        """In ESTOPPED until confirmed: has every axis reported leaving closed loop since the
        e-stop? Past the deadline: name the axes that have not, send Estop and IDLE again."""
        since = self._estop_at_s
        for r in readings:
            if r.heartbeat_stamp_s <= since or r.ready:
                break
        else:
            self._estop_confirmed = True
            if self._estop_unconfirmed:
                late = ", ".join(f"node {n}" for n in self._estop_unconfirmed)
                self._estop_unconfirmed = ()
                self._set_reason(
                    f"estop (confirmed: {late} left closed loop only after "
                    f"{self.estop_repeats} repeat(s) of Estop and IDLE)"
                )
            return
        if now_s < self._estop_check_s:
            return
        self._estop_check_s = now_s + ESTOP_CONFIRM_S
        bad = [r for r in readings if r.heartbeat_stamp_s <= since or r.ready]
        self.estop_repeats += 1
        errors = []
        for send in (self.driver.estop, self.driver.disarm):
            try:
                send()
            except Exception as exc:
                errors.append(str(exc))
        nodes = tuple(r.node_id for r in bad)
        if nodes != self._estop_unconfirmed:
            self._estop_unconfirmed = nodes
            what = ", ".join(
                f"node {r.node_id} still in closed loop ({r.state_name})"
                if r.heartbeat_stamp_s > since
                else f"node {r.node_id} silent (no heartbeat since the Estop)"
                for r in bad
            )
            bus = f" (bus: {'; '.join(errors)})" if errors else ""
            self._set_reason(
                f"estop_unconfirmed: {what} {now_s - since:.2f} s after Estop; "
                f"Estop repeated and IDLE requested{bus}"
            )

    def _disarm(self, why: str) -> None:
        if self._end_pretension() is not None:
            self.pretension_result = {"ok": False, "reason": why}
        try:
            self.driver.disarm()
        except Exception as exc:
            log.error("disarm failed on the bus: %s", exc)
        self.commanded_rev = None
        self.setpoint_m = None
        self.setpoint_lengths_m = None
        self._stream_target = None
        self._velocity_cmd = None
        self._estop_unconfirmed = ()
        self._set_state(State.DISARMED, why)
