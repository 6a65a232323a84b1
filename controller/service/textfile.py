"""Reading the text files a user gives (configuration, path, calibration samples): one way to
say that a file is not UTF-8, where the offending byte is."""

from __future__ import annotations

import os


class NotUtf8Error(ValueError):
    """The bytes are not UTF-8; the message names the first bad byte, its line and column."""


def decode_utf8(raw: bytes) -> str:
    """`raw` decoded as UTF-8.

    Raises NotUtf8Error ("not UTF-8 text: byte 0xe9 at line 1, column 12") naming the first
    byte that is not UTF-8.
    """
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise NotUtf8Error(
            f"not UTF-8 text: byte 0x{raw[exc.start]:02x} at line {line}, column {column}"
        ) from None


def read_text(path: str | os.PathLike[str]) -> str:
    """The UTF-8 text of the file at `path`.

    Raises OSError when it cannot be read and NotUtf8Error when it is not UTF-8.
    """
    with open(path, "rb") as fh:
        return decode_utf8(fh.read())
