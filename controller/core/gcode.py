"""G-code lines: words, comments, line numbers and checksums, in the dialects slicers and CAM
tools write for RepRapFirmware, Marlin and Klipper. Pure: text in, records out; no I/O.

What a line may hold (`parse_line`):

* comments: `;` to the end of the line, and `( ... )` anywhere (RepRapFirmware; Marlin with
  PAREN_COMMENTS); a `;` or `(` inside a quoted string is text, not a comment;
* a line number `N123` as the first word (`N-1`, which hosts send with `M110` to restart the
  numbering at 0, included) and a checksum `*71` after the command: the XOR of
  every byte before the `*` (comments excluded), as RepRap hosts compute it (`checksum`). A
  line with a checksum that does not match raises `ChecksumError`; a checksum without a line
  number is checked too;
* words: a letter (case-insensitive outside strings) and its value, with or without spaces
  between words (`G1X10Y-2.5`):

  - a number (`X-1.5`, `F3000`, `S.5`); no exponents, never NaN or infinity;
  - a colon array (`M92 X80:80:80`, RepRapFirmware);
  - a quoted string (`M23 "my file.gcode"`, `M587 S"net"`), `""` inside it being one `"`;
  - nothing (a flag, as in `G28 X Y` or `M84 E`);

* the command word `G`, `M` or `T` with a code number, dotted codes included (`M569.4`,
  `G29.1`); a second `G` or `M` word starts a second command on the same line (RepRapFirmware
  runs `G91 G1 X10` as two commands);
* a line of axis words without a command (`X10 Y5`, written by CAM tools after a `G1`): a
  `Command` with an empty letter, which the interpreter runs as the modal motion;
* the commands that take free text (`M117 Hello world`, `M23 file.gco`, Marlin's unquoted
  form, or one quoted string, RepRapFirmware's): the rest of the line before a comment or
  checksum is their `text`.

Anything else (RepRapFirmware's meta commands and `{ }` expressions, a word without a letter,
a number that does not parse) raises `GcodeSyntaxError` naming the column. A `%` line (a CAM
program's start and end marker) and a blank line are empty lines.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Final

ParamValue = float | tuple[float, ...] | str | None
"""A word's value: a number, a colon array, a quoted string, or None for a flag."""

TEXT_CODES: Final = frozenset({"M23", "M28", "M30", "M32", "M117", "M118", "M928"})
"""Commands whose parameter is free text up to the comment or checksum (unquoted filenames and
messages, Marlin's form; RepRapFirmware accepts it too)."""

_META: Final = frozenset(
    {"if", "elif", "else", "while", "break", "continue", "abort", "var", "global", "set", "echo"}
)

_NUMBER: Final = r"[+-]?(?:\d+\.?\d*|\.\d+)"
_WORD_RE: Final = re.compile(
    r"[ \t]*([A-Za-z])(?:\"((?:[^\"]|\"\")*)\"|(" + _NUMBER + r"(?::" + _NUMBER + r")*))?[ \t]*"
)
_N_RE: Final = re.compile(r"[ \t]*[Nn](-?\d+)[ \t]*")
_CODE_RE: Final = re.compile(r"(\d+)(?:\.(\d+))?$")
_PLAIN_WORD: Final = r"[A-Za-z](?:" + _NUMBER + r")?"
_PLAIN_RE: Final = re.compile(r"[ \t]*(?:" + _PLAIN_WORD + r"[ \t]+)*" + _PLAIN_WORD + r"[ \t]*")
_PAIR_RE: Final = re.compile(r"([A-Za-z])(\S*)")


class GcodeError(ValueError):
    """A G-code line that cannot be read. `line_no` is its 1-based line in the file or stream
    (0 when not known), `reason` says what is wrong; the message is ``line N: reason``."""

    def __init__(self, line_no: int, reason: str) -> None:
        super().__init__(f"line {line_no}: {reason}" if line_no else reason)
        self.line_no = line_no
        self.reason = reason


class GcodeSyntaxError(GcodeError):
    """A line that breaks the word syntax (a stray character, a bad number, an open string)."""


class ChecksumError(GcodeError):
    """A `*` checksum that does not match the line, or a malformed one. `number` is the line's
    `N` number (None without one): the one a host is asked to resend."""

    def __init__(self, line_no: int, reason: str, number: int | None) -> None:
        super().__init__(line_no, reason)
        self.number = number


@dataclass(frozen=True, slots=True)
class Command:
    """One command of a line: `letter` ("G", "M", "T", or "" for axis words without a
    command), `number` and `sub` (`M569.4`: 569 and 4; `sub` None without a dot), the
    parameter words by upper-case letter, and the free `text` of the `TEXT_CODES`."""

    letter: str
    number: int
    sub: int | None = None
    params: Mapping[str, ParamValue] = field(default_factory=lambda: MappingProxyType({}))
    text: str | None = None

    @property
    def code(self) -> str:
        """The command as written in the documents: "G1", "M569.4", "T0"; "" for none."""
        if not self.letter:
            return ""
        if self.sub is None:
            return f"{self.letter}{self.number}"
        return f"{self.letter}{self.number}.{self.sub}"

    def has(self, letter: str) -> bool:
        """Whether the parameter `letter` (upper case) is present, with or without a value."""
        return letter in self.params

    def number_param(self, letter: str, line_no: int = 0) -> float | None:
        """The numeric value of parameter `letter` (None when absent).

        Raises GcodeSyntaxError when it is present as a flag, a string or an array."""
        if letter not in self.params:
            return None
        v = self.params[letter]
        if isinstance(v, float):
            return v
        raise GcodeSyntaxError(line_no, f"{self.code or 'motion'}: {letter} needs a number")


@dataclass(frozen=True, slots=True)
class Line:
    """A parsed line: `line_no` (1-based position in the input), the `N` line `number` and the
    `checksum` if written, its commands in order (none for a comment or blank line) and the
    text of its comments joined by a space (None without one)."""

    line_no: int
    commands: tuple[Command, ...]
    number: int | None = None
    checksum: int | None = None
    comment: str | None = None


def checksum(text: str) -> int:
    """The RepRap checksum of `text`: the XOR of its UTF-8 bytes, as hosts compute it over
    ``N<n> <command>`` (everything before the `*`). Raises nothing."""
    cs = 0
    for b in text.encode("utf-8"):
        cs ^= b
    return cs


def numbered(number: int, command: str) -> str:
    """The line a host sends for `command` as line `number`: ``N<number> <command>*<cs>``.
    Raises ValueError for a negative line number or a command holding a newline."""
    if number < -1:
        raise ValueError(f"line number {number} is below -1")
    if "\n" in command or "\r" in command:
        raise ValueError("a command is one line")
    body = f"N{number} {command}"
    return f"{body}*{checksum(body)}"


def _split(text: str, line_no: int) -> tuple[str, str | None, str | None]:
    """(code part, checksum digits or None, comment or None) of a line: the code part is what
    comes before `*` and outside comments (the checksum covers exactly it)."""
    if '"' not in text and "(" not in text:
        code, sep, comment = text.partition(";")
        star = code.find("*")
        if star < 0:
            return code, None, comment if sep else None
        return code[:star], code[star + 1 :], comment if sep else None
    parts: list[str] = []
    comments: list[str] = []
    i, n, start = 0, len(text), 0
    cs: str | None = None
    while i < n:
        c = text[i]
        if c == '"':
            j = i + 1
            while True:
                j = text.find('"', j)
                if j < 0:
                    raise GcodeSyntaxError(line_no, f"column {i + 1}: unterminated string")
                if j + 1 < n and text[j + 1] == '"':
                    j += 2
                    continue
                break
            i = j + 1
        elif c == "(":
            close = text.find(")", i + 1)
            if close < 0:
                raise GcodeSyntaxError(line_no, f"column {i + 1}: unterminated ( comment")
            parts.append(text[start:i])
            comments.append(text[i + 1 : close].strip())
            i = start = close + 1
        elif c == ";":
            parts.append(text[start:i])
            comments.append(text[i + 1 :].strip())
            start = i = n
        elif c == "*":
            parts.append(text[start:i])
            rest = text[i + 1 :]
            semi = rest.find(";")
            if semi >= 0:
                comments.append(rest[semi + 1 :].strip())
                rest = rest[:semi]
            cs = rest
            start = i = n
        else:
            i += 1
    parts.append(text[start:])
    return "".join(parts), cs, " ".join(comments) if comments else None


def parse_line(text: str, line_no: int = 0) -> Line:
    """Parse one line of G-code (without its newline) into a `Line`; `line_no` is where it is
    in its input (for messages).

    Raises ChecksumError for a checksum that does not match (or is not a number 0..255) and
    GcodeSyntaxError for a line that does not follow the word syntax (see the module)."""
    code_part, cs_text, comment = _split(text, line_no)
    if comment is not None:
        comment = comment.strip()
    number: int | None = None
    cs: int | None = None
    pos = 0
    m = _N_RE.match(code_part)
    if m is not None:
        number = int(m.group(1))
        pos = m.end()
    if cs_text is not None:
        digits = cs_text.strip()
        if not digits.isdigit() or int(digits) > 255:
            raise ChecksumError(line_no, f"checksum {digits!r} is not a number 0..255", number)
        cs = int(digits)
        actual = checksum(code_part)
        if actual != cs:
            raise ChecksumError(
                line_no, f"checksum {cs} does not match the line's {actual}", number
            )
    body = code_part[pos:]
    stripped = body.strip()
    if not stripped or stripped == "%":
        return Line(line_no, (), number, cs, comment)
    if stripped[0] in "{" or stripped.split(None, 1)[0].lower() in _META:
        raise GcodeSyntaxError(
            line_no,
            "RepRapFirmware meta commands and { } expressions are not supported: "
            f"{stripped[:40]!r}",
        )
    return Line(line_no, _commands(body, pos, line_no), number, cs, comment)


_Word = tuple[str, str | None, str | None, int]
"""(letter, quoted string or None, number text or None, end position in the body or -1)."""


def _fast_words(body: str) -> list[_Word] | None:
    """The words of a body of whitespace-separated words, each one letter and a number (or a
    flag): what slicers write, read with two regular-expression calls. None for anything else
    (the general scanner reads it)."""
    if _PLAIN_RE.fullmatch(body) is None:
        return None
    return [(w, None, num or None, -1) for w, num in _PAIR_RE.findall(body)]


def _scan_words(body: str, offset: int, line_no: int) -> list[_Word]:
    out: list[_Word] = []
    pos, n = 0, len(body)
    while pos < n:
        m = _WORD_RE.match(body, pos)
        if m is None or m.end() == pos:
            col = offset + pos + 1 + (len(body[pos:]) - len(body[pos:].lstrip()))
            rest = body[pos:].strip()
            raise GcodeSyntaxError(line_no, f"column {col}: cannot read {rest[:20]!r}")
        out.append((m.group(1), m.group(2), m.group(3), m.end()))
        pos = m.end()
        if m.group(1) in "Mm" and f"M{m.group(3)}" in TEXT_CODES:
            break  # the rest is the command's text
    return out


def _commands(body: str, offset: int, line_no: int, fast: bool = True) -> tuple[Command, ...]:
    """The commands of a line's code part (after its `N` word)."""
    words = _fast_words(body) if fast and '"' not in body else None
    if words is None:
        words = _scan_words(body, offset, line_no)
    out: list[Command] = []
    letter = ""
    number = 0
    sub: int | None = None
    params: dict[str, ParamValue] = {}
    for w, s, num, end in words:
        w = w.upper()
        if w in "GM" or (w == "T" and not letter and not params):
            if num is None or ":" in num:
                raise GcodeSyntaxError(line_no, f"{w} needs a code number")
            cm = _CODE_RE.match(num)
            if cm is None:
                raise GcodeSyntaxError(line_no, f"{w}{num}: not a code number")
            if letter or params:
                out.append(Command(letter, number, sub, MappingProxyType(params)))
                params = {}
            letter, number = w, int(cm.group(1))
            sub = None if cm.group(2) is None else int(cm.group(2))
            code = f"{letter}{number}" if sub is None else f"{letter}{number}.{sub}"
            if code in TEXT_CODES:
                if end < 0:  # read by the fast path: find the text with the scanner
                    return _commands(body, offset, line_no, fast=False)
                rest = body[end:].strip()
                if rest:
                    if len(rest) >= 2 and rest[0] == '"' and rest[-1] == '"':
                        rest = rest[1:-1].replace('""', '"')
                    out.append(Command(letter, number, sub, MappingProxyType({}), rest))
                    return tuple(out)
            continue
        value: ParamValue
        if s is not None:
            value = s.replace('""', '"')
        elif num is None:
            value = None
        elif ":" in num:
            value = tuple(float(x) for x in num.split(":"))
            if not all(math.isfinite(x) for x in value):
                raise GcodeSyntaxError(line_no, f"{w}: {num[:20]} is out of range")
        else:
            value = float(num)
            if value - value != 0.0:  # inf from a number of 300 digits
                raise GcodeSyntaxError(line_no, f"{w}: {num[:20]} is out of range")
        if w in params:
            raise GcodeSyntaxError(line_no, f"{w} given twice")
        params[w] = value
    out.append(Command(letter, number, sub, MappingProxyType(params)))
    return tuple(out)


def parse_lines(lines: Iterable[str], first_line_no: int = 1) -> Iterator[Line]:
    """Parse `lines` (with or without their newlines), numbering them from `first_line_no`.
    Raises what `parse_line` raises, at the first bad line."""
    for i, text in enumerate(lines, first_line_no):
        yield parse_line(text.rstrip("\r\n"), i)
