"""`cablebot gcode --serial [PATH]`: a pseudo-terminal that speaks the RepRap line protocol, so
that hosts written for printers (Printrun/Pronterface, OctoPrint, a CAM tool's sender) stream
G-code to the robot (docs/gcode.md).

Opens a pseudo-terminal in raw mode, links PATH to it (a stable name for the host's settings;
the link is replaced atomically and removed at the end) and prints its path. Each line the host
sends goes through `controller.core.gcode_protocol.LineProtocol` (line numbers, checksums,
`Resend:`, `M105`/`M115`), then `controller.core.gcode_job.Interpreter`; its motions gather
into chunks sent to the daemon by the same `Streamer` as `cablebot gcode FILE`, a chunk going
out when it holds `CHUNK_POINTS` points, at a wait, or when the host pauses for `IDLE_S`.
`ok` goes back once a line is queued (a chunk waits while the daemon has `LOW_WATER_S` of motion
queued or its queue is full, `controller.client.stream.Pacer`: that delay is the host's flow
control).
During a wait (`G4`, `M400`, `M114`) the host hears `echo:busy: processing` every 2 s.

Unlike a file, a stream cannot be checked whole before its first move: the daemon checks every
chunk against the workspace and the tension rule. A refused chunk stops the job (the robot
brakes to a hold) and every motion line after it is answered `Error:` until the host sends
`M999`, which starts again from where the robot rests, the job's modal state (units, absolute
or relative, feed) kept.
"""

from __future__ import annotations

import argparse
import math
import os
import select
import time
import tty
from contextlib import suppress
from typing import Any

from controller.cli import exitcodes
from controller.cli.gcode import _fail
from controller.client.errors import DaemonAbsent, Refused
from controller.client.gcode import frame_of
from controller.client.job import JobLink, RobotJobLink, Streamer, chunk_points
from controller.core.commands import C_DECODE_MAX_BYTES, MAX_PATH_POINTS_SENT
from controller.core.gcode import GcodeError
from controller.core.gcode_job import Chunk, Interpreter, Motion, Step, Vec3, chunks
from controller.core.gcode_protocol import BUSY, BUSY_INTERVAL_S, LineProtocol

CHUNK_POINTS = chunk_points(MAX_PATH_POINTS_SENT, C_DECODE_MAX_BYTES)
"""Points gathered before a chunk goes to the daemon (its fast JSON decoder's limit)."""
IDLE_S = 0.1
"""A host silent this long: the motions gathered so far go to the daemon."""
MAX_LINE_BYTES = 1024
"""A longer line is answered `Error:` (a host never sends one; junk must not grow memory)."""


class SerialJob:
    """The state of one serial session: protocol, interpreter, the motions not yet sent, and
    whether a refusal halted the job."""

    def __init__(self, robot: JobLink, cfg: Any, write: Any) -> None:
        self.robot = robot
        self.cfg = cfg
        self.write = write
        self.proto = LineProtocol()
        self.streamer = Streamer(robot)
        self.streamer.on_wait = self._busy
        self._busy_next = 0.0
        self._busy_last = -math.inf
        self.pending: list[Motion] = []
        self.pending_points = 0
        self.halted: str | None = None
        self.interp = self._new_interpreter()

    def _rest_point(self) -> Vec3:
        """Where the robot rests (its set-point, else its pose): where motion lines start."""
        st = self.robot.status()
        p = st.get("setpoint_m") or st.get("pose", {}).get("position_m") or [0.0, 0.0, 0.0]
        return (float(p[0]), float(p[1]), float(p[2]))

    def _new_interpreter(self) -> Interpreter:
        return Interpreter(frame_of(self.cfg), self._rest_point())

    def _restart(self) -> None:
        """`M999`: take motion lines again, from where the robot rests. The job's modal state
        (units, absolute or relative, feed rate and `M220`, `G92`, lowered limits) is kept, as
        a firmware keeps it: a host resumes with the lines after the refused one, whose moves
        carry no new `F`."""
        self.halted = None
        self.streamer.fresh = True
        self.interp.pos_m = self._rest_point()

    def _busy(self) -> None:
        now = time.monotonic()
        if now - self._busy_last > 1.0:  # a new wait: the first keep-alive after the interval
            self._busy_next = now + BUSY_INTERVAL_S
        self._busy_last = now
        if now >= self._busy_next:
            self._busy_next = now + BUSY_INTERVAL_S
            self.write(BUSY)

    def _halt(self, why: str) -> None:
        self.halted = why
        self.pending = []
        self.pending_points = 0
        self.write(f"Error:{why}")
        with suppress(Refused, DaemonAbsent):
            self.robot.command("stop")

    def flush(self) -> None:
        """Send the gathered motions (as path or appends)."""
        if not self.pending:
            return
        acts, self.pending, self.pending_points = self.pending, [], 0
        for step in chunks(acts, CHUNK_POINTS):
            self._send(step)

    def _send(self, step: Step) -> str | None:
        try:
            return self.streamer.send(step)
        except Refused as exc:
            self._halt(f"refused: {exc}")
            return None

    def line(self, text: str) -> None:
        """Take one line from the host and answer it."""
        r = self.proto.receive(text)
        for reply in r.replies:
            self.write(reply)
        if r.line is not None:
            if any(c.code == "M999" for c in r.line.commands):
                self._restart()
            elif self.halted is not None:
                self.write(f"Error:job halted ({self.halted}); send M999 to start again")
            else:
                try:
                    actions = self.interp.feed(r.line)
                except GcodeError as exc:
                    self._halt(exc.reason)
                    actions = []
                for act in actions:
                    if isinstance(act, Motion):
                        self.pending.append(act)
                        self.pending_points += len(act.points_m)
                        if self.pending_points >= CHUNK_POINTS:
                            self.flush()
                        continue
                    self.flush()
                    if self.halted is not None:
                        break
                    for step in chunks([act], 1):
                        if isinstance(step, Chunk):
                            continue
                        report = self._send(step)
                        if report is not None:
                            self.write(report)
        if r.ok:
            self.write("ok")


def serve(master: int, job: SerialJob, write: Any) -> None:
    """Read the host's lines from the pseudo-terminal `master` and hand each to `job`, the
    gathered motions flushed whenever the host pauses for `IDLE_S`; runs until interrupted
    (KeyboardInterrupt). Raises what `job` raises (the daemon absent)."""
    buf = b""
    while True:
        ready, _, _ = select.select([master], [], [], IDLE_S)
        if not ready:
            job.flush()
            continue
        try:
            data = os.read(master, 4096)
        except OSError:  # the host closed its end: wait for the next one
            data = b""
        if not data:
            time.sleep(IDLE_S)
            continue
        buf += data
        while True:
            cut = min((i for i in (buf.find(b"\n"), buf.find(b"\r")) if i >= 0), default=-1)
            if cut < 0:
                if len(buf) > MAX_LINE_BYTES:
                    buf = b""
                    write("Error:line too long")
                break
            raw, buf = buf[:cut], buf[cut + 1 :]
            if raw.strip():
                job.line(raw.decode("utf-8", errors="replace"))


def cmd_serial(args: argparse.Namespace) -> int:
    """`gcode --serial [PATH]`: serve the line protocol on a pseudo-terminal for the daemon's
    robot until Ctrl-C, SIGTERM or SIGHUP (each stops the job: the robot brakes to a hold)."""
    from controller.cli import client
    from controller.cli.daemon_robot import daemon_robot

    master, slave = os.openpty()
    tty.setraw(slave)
    name = os.ttyname(slave)
    link = args.serial if args.serial else None
    try:
        if link is not None:
            tmp = f"{link}.{os.getpid()}.tmp"
            os.symlink(name, tmp)
            os.replace(tmp, link)
    except OSError as exc:
        os.close(master)
        os.close(slave)
        return _fail(f"--serial {link}: {exc}")

    def write(text: str) -> None:
        os.write(master, (text + "\n").encode("ascii", errors="replace"))

    def body(session: Any) -> int:
        robot = client.robot_of(args, session)
        # The daemon's robot interprets the host's G-code (a --config must agree with it).
        cfg = daemon_robot(robot, args.config).config
        job = SerialJob(RobotJobLink(robot), cfg, write)
        print(f"gcode: serial port {link or name}" + (f" -> {name}" if link else ""), flush=True)
        try:
            with client.signals_interrupt():  # SIGTERM, SIGHUP: stop the job as Ctrl-C does
                serve(master, job, write)
        except KeyboardInterrupt:
            return client._interrupted(robot, args)
        return exitcodes.OK

    try:
        return client.run_with_session(args, body)
    finally:
        os.close(master)
        os.close(slave)
        if link is not None:
            with suppress(OSError):
                if os.path.islink(link) and os.readlink(link) == name:
                    os.unlink(link)
