"""What the client verbs print: poses, status, command replies, the home and pre-tension
results, the `list` table; following a stream (sequence gaps, a progress line rewritten in
place on a terminal). The pose line, a point and the distance left along a path are the client
library's (`controller.client.model`, `controller.client.arrival`), importable from here.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TextIO

from controller.client.arrival import path_remaining_m
from controller.client.model import pose_text
from controller.client.model import xyz_text as format_xyz

__all__ = [
    "PROGRESS_PERIOD_S",
    "SeqGaps",
    "StatusLine",
    "axis_fault_text",
    "axis_state_text",
    "format_daemons",
    "format_home",
    "format_pose",
    "format_pretension_result",
    "format_reply",
    "format_status",
    "format_xyz",
    "is_tty",
    "path_remaining_m",
    "setpoints_line",
    "status_tensions_n",
]

PROGRESS_PERIOD_S = 0.1
"""How often the progress line is rewritten, at most."""


# --------------------------------------------------------------------------------------------
# Formatting


def format_pose(sample: dict[str, Any]) -> str:
    """One human-readable line for a pose sample (`controller.client.model.pose_text`)."""
    return pose_text(
        sample.get("seq"), sample.get("state"), sample.get("position_m"), sample.get("residual_m")
    )


def axis_state_text(ax: dict[str, Any]) -> str:
    """An axis's state as its drive names it (the status entry's "state", e.g.
    "CLOSED_LOOP_CONTROL" or "Operation enabled"); "state N" from the raw number when the
    entry has no name."""
    name = ax.get("state")
    if isinstance(name, str) and name:
        return name
    return f"state {ax.get('axis_state')}"


def axis_fault_text(ax: dict[str, Any]) -> str:
    """An axis's fault as its drive names it (the status entry's "fault", e.g.
    "ESTOP_REQUESTED (0x2000000)"), "none" without one; the raw error number when the entry
    has no name."""
    if "fault" in ax:
        fault = ax["fault"]
        return "none" if fault is None else str(fault)
    err = ax.get("axis_error")
    if isinstance(err, int) and not isinstance(err, bool):
        return "none" if err == 0 else f"0x{err:x}"
    return str(err)


def status_tensions_n(st: dict[str, Any]) -> list[float | None] | None:
    """The cable tensions (N, cable order) a status carries, or None when it has none."""
    for holder in (st, st.get("statics"), st.get("pose")):
        if isinstance(holder, dict) and isinstance(holder.get("tensions_n"), list):
            return [v if isinstance(v, int | float) else None for v in holder["tensions_n"]]
    return None


def format_status(st: dict[str, Any]) -> str:
    """A short multi-line summary of a status reply (axis states and faults by the drives'
    names)."""
    lines = [f"state      {st.get('state')}" + (f" ({st['reason']})" if st.get("reason") else "")]
    pose = st.get("pose") or {}
    if pose.get("position_m") is not None:
        x, y, z = pose["position_m"]
        lines.append(f"position   x={x:+.4f} y={y:+.4f} z={z:+.4f} m")
    else:
        lines.append("position   not valid")
    sp = st.get("setpoint_m")
    if isinstance(sp, list) and len(sp) == 3:
        lines.append(f"set-point  x={sp[0]:+.4f} y={sp[1]:+.4f} z={sp[2]:+.4f} m")
    if "homed" in st:
        lines.append(f"homed      {st.get('homed')} ({st.get('home_source')})")
    pt = st.get("pretension")
    if isinstance(pt, dict):
        res = pt.get("result")
        if pt.get("active"):
            fastest = pt.get("fastest_cable_mps")
            speed = "" if fastest is None else f", fastest cable {fastest * 1e3:.1f} mm/s"
            lines.append(
                f"pretension running {float(pt.get('elapsed_s') or 0.0):.1f} s{speed}, home at "
                f"{format_xyz(pt.get('position_m') or [])}"
            )
        elif isinstance(res, dict):
            lines.append(
                f"pretension still after {float(res.get('still_after_s', 0.0)):.2f} s, homed"
                if res.get("ok")
                else f"pretension ended without homing: {res.get('reason')}"
            )
    shaper = st.get("shaper")
    if isinstance(shaper, dict):
        from controller.cli.shaper_cmd import describe

        lines.append(f"shaper     {describe(shaper)}")
    tensions = status_tensions_n(st)
    for i, ax in enumerate(st.get("axes", [])):
        age = ax.get("age_s")
        age_s = "never" if age is None else f"{age * 1e3:.1f} ms ago"
        tension = ""
        if tensions is not None and i < len(tensions) and tensions[i] is not None:
            tension = f"  tension {tensions[i]:.1f} N"
        lines.append(
            f"axis {ax.get('node_id')!s:<5} {axis_state_text(ax)}, error"
            f" {axis_fault_text(ax)}, reading {age_s}{tension}"
        )
    lp = st.get("loop")
    if lp:
        lines.append(
            f"loop       {lp.get('rate_hz')} Hz, ticks {lp.get('ticks')}, overruns"
            f" {lp.get('overruns')}, jitter p99 {_ms(lp.get('jitter_p99_s'))},"
            f" compute p99 {_ms(lp.get('compute_p99_s'))}"
        )
    bus = st.get("bus")
    if bus:
        lines.append(
            f"bus        rx {bus.get('frames_rx')} tx {bus.get('frames_tx')} errors"
            f" {bus.get('bus_errors')} decode errors {bus.get('decode_errors')}"
            f" dropped {bus.get('dropped')}"
            f"  commands heard {bus.get('commands_heard', 0)} (own echoes or another master)"
        )
        if bus.get("conflicts"):
            lines.append(
                f"           another master heard {bus['conflicts']}x: {bus.get('last_conflict')}"
            )
    z = st.get("zenoh")
    if z:
        put = z.get("pose_put") or {}
        tick = z.get("pose_publish_tick") or {}
        cmds = z.get("commands") or {}
        lines.append(
            f"zenoh      {z.get('mode')} {', '.join(z.get('listen') or [])}, prefix"
            f" {z.get('prefix')}; poses {z.get('poses_published')}, put p50/p99"
            f" {_us(put.get('p50_us'))}/{_us(put.get('p99_us'))}, tick cost p50/p99"
            f" {_us(tick.get('p50_us'))}/{_us(tick.get('p99_us'))}"
        )
        lines.append("commands   " + ", ".join(f"{k} {v}" for k, v in cmds.items()))
    stream = st.get("stream")
    if z or isinstance(stream, dict):
        lines.append(setpoints_line((z or {}).get("setpoints"), stream))
    cfg = st.get("config")
    if isinstance(cfg, dict) and "name" in cfg:
        loop_cfg = cfg.get("loop") or {}
        lines.append(
            f"config     robot {cfg.get('name')!r} from {cfg.get('source')},"
            f" {len(cfg.get('reels') or [])} reels, loop {loop_cfg.get('rate_hz')} Hz"
        )
    return "\n".join(lines)


def setpoints_line(received: Any, stream: Any) -> str:
    """The status line of the streamed set-points: how many arrived (and were malformed), how
    many the daemon refused (with the last reason) and discarded (not armed)."""
    parts = []
    if isinstance(received, dict):
        ok, bad = received.get("ok") or 0, received.get("bad") or 0
        parts += [f"received {ok + bad}", f"malformed {bad}"]
    if isinstance(stream, dict):
        for kind, last in (("refused", "last_refusal"), ("discarded", "last_discard")):
            n = stream.get(kind) or 0
            why = stream.get(last)
            parts.append(f"{kind} {n}" + (f" (last: {why})" if n and why else ""))
    return "set-points " + ", ".join(parts)


def format_reply(verb: str, reply: Any) -> str:
    """One readable line for a command's reply (what the robot does now)."""
    if not isinstance(reply, dict):
        return f"{verb}: ok"
    state = reply.get("state")
    if verb == "stop":
        if state == "MOVING":
            return "stop: braking to a hold"
        if state == "HOLDING":
            return "stop: holding (nothing was moving)"
        return f"stop: nothing to stop (state {state})"
    if verb == "home":
        return format_home(reply)
    if verb == "pretension":
        tensions = reply.get("tensions_n")
        text = "pretension: the reels pull in torque control"
        if isinstance(tensions, list) and tensions:
            text += " with " + ", ".join(f"{float(t):.1f}" for t in tensions) + " N"
        if reply.get("speed_limited") is False:
            text += " (the drives' own velocity limit caps their speed)"
        return text + "; waiting until they are still"
    known = {"ok", "state"}
    if verb in ("move", "path"):
        known |= {"target_m", "points", "speed_mps", "speed_limited_to_mps", "append"}
        known |= {"queued_points", "queued_s", "queue_full"}
        speed = reply.get("speed_mps")
        at = "" if not isinstance(speed, int | float) else f" at {speed:.3f} m/s"
        limited = reply.get("speed_limited_to_mps")
        if isinstance(limited, int | float):
            at += f" (speed limited to the robot's maximum, {limited:.3f} m/s)"
        target = reply.get("target_m")
        if verb == "move" and isinstance(target, list):
            text = f"move: to {format_xyz(target)}{at}"
        elif verb == "path" and isinstance(reply.get("points"), int):
            added = "appended" if reply.get("append") is True else "points"
            text = f"path: {reply['points']} {added}{at}"
            queued, queued_s = reply.get("queued_points"), reply.get("queued_s")
            if isinstance(queued, int) and isinstance(queued_s, int | float):
                full = ", full" if reply.get("queue_full") is True else ""
                text += f"; {queued} queued ({queued_s:.1f} s{full})"
        else:
            text = f"{verb}: ok{at}"
    else:
        text = f"{verb}: ok" + (f", state {state}" if state is not None else "")
    extra = " ".join(f"{k}={v}" for k, v in reply.items() if k not in known)
    return f"{text} {extra}".rstrip()


def format_home(reply: dict[str, Any]) -> str:
    """The `home` reply: the declared position, the offsets (4 decimals of a turn), saved where."""
    parts = ["home:"]
    pos = reply.get("position_m")
    if isinstance(pos, list):
        parts.append(f"at {format_xyz(pos, 4)};")
    offsets = reply.get("offsets_rev")
    if isinstance(offsets, dict) and offsets:
        parts.append(
            "offsets (turns) "
            + ", ".join(f"node {k} {float(v):+.4f}" for k, v in offsets.items())
            + ";"
        )
    if reply.get("saved"):
        parts.append(f"saved to {reply.get('state_file')}")
    elif reply.get("saving"):
        parts.append(f"saving to {reply.get('state_file')} (not confirmed yet: see `status`)")
    elif reply.get("error"):
        parts.append(f"NOT SAVED: {reply['error']}")
    else:
        parts.append("not saved (no [homing] state_file)")
    return " ".join(parts)


def _ms(v: Any) -> str:
    return "-" if v is None else f"{float(v) * 1e3:.2f} ms"


def _us(v: Any) -> str:
    return "-" if v is None else f"{float(v):.0f} us"


# --------------------------------------------------------------------------------------------
# Following a stream: sequence gaps, rate limiting, progress


class SeqGaps:
    """Counts samples missed from a stream numbered by `seq` (one per published sample).

    `update(seq)` returns how many samples were missed just before this one (0 when in
    order). A `seq` that goes backwards means the daemon restarted: counting starts again.
    """

    def __init__(self) -> None:
        self.last: int | None = None
        self.received = 0
        self.missed = 0
        self.restarts = 0

    def update(self, seq: Any) -> int:
        """Record one received `seq`; returns the samples missed before it."""
        self.received += 1
        if not isinstance(seq, int):
            return 0
        gap = 0
        if self.last is not None:
            if seq <= self.last:
                self.restarts += 1
            else:
                gap = seq - self.last - 1
        self.last = seq
        self.missed += gap
        return gap


class StatusLine:
    """One line of progress rewritten in place on a terminal; does nothing elsewhere."""

    def __init__(self, stream: TextIO, *, enabled: bool) -> None:
        self.stream = stream
        self.enabled = enabled
        self._shown = False
        self._next_s = 0.0

    def show(self, text: str, now_s: float) -> None:
        """Replace the line with `text` (at most every PROGRESS_PERIOD_S)."""
        if not self.enabled or now_s < self._next_s:
            return
        self._next_s = now_s + PROGRESS_PERIOD_S
        self.stream.write("\r\x1b[K" + text)
        self.stream.flush()
        self._shown = True

    def clear(self) -> None:
        """Erase the line (before printing a normal line)."""
        if self._shown:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
            self._shown = False


def is_tty(stream: Any) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def format_pretension_result(result: dict[str, Any]) -> str:
    """The end of a pre-tension: how long until still, where homed, the tensions."""
    parts = [
        f"pretension: still after {float(result.get('still_after_s', 0.0)):.2f} s",
        "homed " + format_home(result).removeprefix("home: "),
    ]
    measured = result.get("measured_tensions_n")
    if isinstance(measured, list) and measured and None not in measured:
        parts.append("measured tensions " + ", ".join(f"{t:.1f}" for t in measured) + " N")
    return "; ".join(parts)


def format_daemons(rows: Sequence[dict[str, Any]]) -> str:
    """The `list` table: one line per daemon (prefix, name, state, endpoints)."""
    table = [("PREFIX", "NAME", "STATE", "ENDPOINT")]
    for r in rows:
        listen = r.get("listen")
        table.append(
            (
                str(r["prefix"]),
                "-" if r.get("name") is None else str(r["name"]),
                "-" if r.get("state") is None else str(r["state"]),
                "-" if not listen else ", ".join(str(e) for e in listen),
            )
        )
    widths = [max(len(row[i]) for row in table) for i in range(3)]
    return "\n".join(
        "  ".join(cell.ljust(w) for cell, w in zip(row[:3], widths, strict=True)) + "  " + row[3]
        for row in table
    )
