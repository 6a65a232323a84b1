"""A caller's numbers checked before anything is sent: points, speeds, path files.

The rules are the daemon's (`controller.core.commands`: finite numbers, at most
`MAX_PATH_POINTS_SENT` points a command; `controller.core.motion.check_speed`); here they only
fail early, with the caller's names for the values, so a bad input costs no round trip and a
long path is refused whole before its first point moves the robot.
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterable, Sequence
from typing import Any

from controller.client.errors import InputError
from controller.core.commands import MAX_PATH_POINTS_SENT, CommandError, parse_command
from controller.core.motion import check_speed

Vec3 = tuple[float, float, float]


def point(values: Any, what: str) -> list[float]:
    """`values` as [x, y, z] of finite floats. Raises InputError naming `what` otherwise."""
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected three finite numbers, got {values!r}") from None
    if len(out) != 3 or not all(math.isfinite(v) for v in out):
        raise InputError(f"{what}: expected three finite numbers, got {values}")
    return out


def points(values: Iterable[Any], what: str) -> list[list[float]]:
    """Every point of `values` as [x, y, z] of finite floats (at least one). Raises InputError
    naming `what` and the first bad point's index."""
    out: list[list[float]] = []
    for i, p in enumerate(values):
        out.append(point(p, f"{what}[{i}]"))
    if not out:
        raise InputError(f"{what}: expected at least one point")
    return out


def speed(value: float | None, what: str) -> float | None:
    """`value` when it is None (the robot's own speed) or a speed the daemon takes. Raises
    InputError naming `what` otherwise."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{what}: expected a number of metres per second, got {value!r}")
    reason = check_speed(float(value))
    if reason is not None:
        raise InputError(f"{what} {reason}")
    return float(value)


def positive_s(value: float, what: str) -> float:
    """`value` when it is a finite number of seconds > 0. Raises InputError otherwise."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{what}: expected a number of seconds, got {value!r}")
    if not (math.isfinite(value) and value > 0.0):
        raise InputError(f"{what} must be a number of seconds > 0, got {value:g}")
    return float(value)


# --------------------------------------------------------------------------------------------
# Path files


def load_path_file(path: str, *, stream: bool = False) -> dict[str, Any]:
    """Read a path file: JSON (a list of [x, y, z] or {"points_m": ..., "speed_mps": ...}) or
    CSV/whitespace lines `x,y,z` (`#` comments and a header line are skipped).

    Returns the `path` command payload. With `stream`, a file of any length (sent as a path
    and appended chunks: every chunk is checked as the command it becomes); without, at most
    the points one command carries. Raises InputError for an unreadable, not UTF-8 or invalid
    file.
    """
    return read_path_file(path, stream=stream)[0]


def read_path_file(path: str, *, stream: bool = False) -> tuple[dict[str, Any], list[int] | None]:
    """`load_path_file`, and the file's line number of every point (None for JSON, whose
    points are named by their position). Raises as `load_path_file` does."""
    from controller.service.textfile import NotUtf8Error, read_text

    try:
        text = read_text(path)
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}") from None
    except NotUtf8Error as exc:
        raise InputError(f"{path}: {exc}") from None
    stripped = text.lstrip()
    payload: dict[str, Any]
    line_of: list[int] | None = None
    if stripped.startswith(("[", "{")):
        try:
            data = json.loads(text, parse_constant=_no_constant)
        except ValueError as exc:
            raise InputError(f"{path}: invalid JSON: {exc}") from None
        if isinstance(data, list):
            payload = {"points_m": data}
        elif isinstance(data, dict):
            payload = dict(data)
        else:
            raise InputError(f"{path}: expected a list of points or an object")
        check_json_points(path, payload.get("points_m"))
    else:
        pts_read, line_of = _csv_points(path, text)
        if not pts_read:
            what = "empty" if not text.strip() else "only a header, comments or blank lines"
            raise InputError(f"{path}: no points in it ({what}): nothing to fly")
        payload = {"points_m": pts_read}
    pts = payload.get("points_m")
    if isinstance(pts, list) and len(pts) > MAX_PATH_POINTS_SENT and not stream:
        raise InputError(
            f"{path}: {len(pts)} points; one path command takes at most {MAX_PATH_POINTS_SENT}"
            f" points: split it into parts of at most {MAX_PATH_POINTS_SENT} points and send"
            " each with its own path command"
        )
    parts = [payload]
    if isinstance(pts, list) and len(pts) > MAX_PATH_POINTS_SENT:
        rest = {k: v for k, v in payload.items() if k != "points_m"}
        parts = [
            {**rest, "points_m": pts[i : i + MAX_PATH_POINTS_SENT]}
            for i in range(0, len(pts), MAX_PATH_POINTS_SENT)
        ]
    for i, part in enumerate(parts):
        try:
            parse_command("path", json.dumps(part))
        except (CommandError, ValueError) as exc:
            where = f" (points {i * MAX_PATH_POINTS_SENT} on)" if i else ""
            raise InputError(f"{path}{where}: {exc}") from None
    return payload, line_of


def check_json_points(path: str, pts: Any) -> None:
    """Refuse the points of a JSON path file as the daemon would, naming a bad one by its
    position in the file from 1 (as the whole-file check does), not by its index in the
    chunk it would be sent in. Raises InputError."""
    from controller.core.commands import parse_point

    if not isinstance(pts, list):
        return  # not a list: the command's own check names it
    if not pts:
        raise InputError(f"{path}: no points in it (an empty list): nothing to fly")
    for i, p in enumerate(pts):
        try:
            parse_point(p, f"point {i + 1}")
        except CommandError as exc:
            raise InputError(f"{path}: {exc}") from None


def _csv_points(path: str, text: str) -> tuple[list[list[float]], list[int]]:
    """The points of CSV or whitespace-separated `x,y,z` lines and the line of each. Raises
    InputError naming the line of the first bad one."""
    out: list[list[float]] = []
    line_of: list[int] = []
    header_seen = False
    rows = csv.reader(io.StringIO(text.replace("\t", ",")))
    for n, row in enumerate(rows, start=1):
        cells = [c for part in row for c in part.split()]
        if not cells or cells[0].startswith("#"):
            continue
        try:
            values = [float(c) for c in cells]
        except ValueError:
            if not out and not header_seen:
                header_seen = True  # a header line such as "x,y,z"
                continue
            raise InputError(f"{path} line {n}: expected x,y,z, got {row}") from None
        out.append(point(values, f"{path} line {n}"))
        line_of.append(n)
    return out, line_of


def _no_constant(name: str) -> Any:
    raise ValueError(f"non-finite number {name}")


def as_vec3(p: Sequence[float]) -> Vec3:
    """A checked point as a tuple."""
    return (float(p[0]), float(p[1]), float(p[2]))
