"""The RepRap serial line protocol, as Marlin and RepRapFirmware speak it to hosts (Printrun,
OctoPrint, Pronterface): which lines to run, which to have sent again, what to answer. Pure:
text lines in, replies out; the terminal I/O and the job are the caller's.

A host numbers its lines `N<n> <command>*<checksum>` (`controller.core.gcode.numbered`) and
sends the next one when the firmware answers `ok`. `LineProtocol.receive` takes one received
line and says:

* `line`: the parsed line to run (None: nothing to run);
* `replies`: what to send before the `ok` (`Error:...` then `Resend: <n>` when a line is to be
  sent again; the answer of `M105`/`M115`);
* `ok`: whether to answer `ok` once the line is queued (always, as Marlin does, so a host
  never waits forever; after a `Resend:` the host sends that line next).

Line numbers (as Marlin's `GCodeQueue`): a numbered line must carry a checksum and be the last
good number plus one; otherwise `Error:` and `Resend: <last + 1>` and the line is dropped. A
bad checksum asks for the same. `M110` sets the number (`N-1 M110` or `M110 N-1`: the next line
is 0). Lines without a number are run as they come (a terminal user typing).

`M105` is answered `ok T:0.0 /0.0` (no heater: hosts need a temperature in the answer),
`M115` with the firmware line `FIRMWARE_NAME:cablebot ... PROTOCOL_VERSION:1.0
MACHINE_TYPE:cablebot EXTRUDER_COUNT:0`. `M114` is the job's to answer (it knows the position:
`controller.core.gcode_job`), after the moves before it. `BUSY` is the keep-alive line a
firmware sends every `BUSY_INTERVAL_S` while a long command (a dwell, `M400`) runs, so the
host's time-out does not fire.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from controller.core.gcode import ChecksumError, GcodeError, Line, parse_line

BUSY: Final = "echo:busy: processing"
BUSY_INTERVAL_S: Final = 2.0
PROTOCOL_VERSION: Final = "1.0"


@dataclass(frozen=True, slots=True)
class Received:
    """What to do with one received line (see the module)."""

    line: Line | None
    replies: tuple[str, ...] = ()
    ok: bool = True


class LineProtocol:
    """The line numbering and answers of one serial connection. `firmware` names cablebot
    and its version in the `M115` answer."""

    def __init__(self, firmware: str = "cablebot") -> None:
        self.firmware = firmware
        self.last_number = 0
        """The last good line number (the next numbered line must be this plus one)."""
        self.resends = 0
        """How many times a line was asked for again."""
        self.received = 0

    def _resend(self, error: str) -> Received:
        self.resends += 1
        return Received(
            None,
            (f"Error:{error}, Last Line: {self.last_number}", f"Resend: {self.last_number + 1}"),
        )

    def receive(self, text: str) -> Received:
        """Take one received line (without its newline). Raises nothing: a line that cannot be
        read is answered `Error:` (and `Resend:` if it was numbered)."""
        self.received += 1
        try:
            line = parse_line(text.strip(), self.received)
        except ChecksumError:
            return self._resend("checksum mismatch")
        except GcodeError as exc:
            if text.lstrip()[:1] in ("N", "n"):
                return self._resend(f"cannot read the line: {exc.reason}")
            return Received(None, (f"Error:{exc.reason}",))
        is_m110 = bool(line.commands) and line.commands[0].code == "M110"
        if line.number is not None:
            if line.checksum is None:
                return self._resend("No Checksum with line number")
            if line.number != self.last_number + 1 and not is_m110:
                return self._resend("Line Number is not Last Line Number+1")
            self.last_number = line.number
        if not line.commands:
            return Received(None)
        code = line.commands[0].code
        if is_m110:
            n = line.commands[0].params.get("N")
            if isinstance(n, float):
                self.last_number = int(n)
            return Received(None)
        if code == "M105":
            return Received(None, ("ok T:0.0 /0.0",), ok=False)  # the answer is the ok
        if code == "M115":
            return Received(
                None,
                (
                    f"FIRMWARE_NAME:{self.firmware} PROTOCOL_VERSION:{PROTOCOL_VERSION} "
                    "MACHINE_TYPE:cablebot EXTRUDER_COUNT:0",
                ),
            )
        return Received(line)
