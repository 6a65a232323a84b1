"""Homing state file: the reel offsets, saved atomically and reloaded on restart.

The ODrive encoders are relative: at power-up every motor reads (about) 0 turns, whatever the
cable lengths. Homing ties each motor position to a cable length, either from the configured
power-up pose (`homing.power_up_position_m`) or when the operator runs `home` with the
effector at a known pose. The resulting per-node offsets (`ReelModel.offset_rev`) are saved
here so that a restart of the *controller* does not need a new homing.

**The offsets are only valid while the ODrives keep power.** After an ODrive power cycle (or
reboot, or an encoder re-index) its position restarts near 0 and the saved offsets describe a
different zero: home again. The record stores the wall time of the save so an operator can tell
how old it is; the loop may additionally compare the motors' positions with the saved ones.

Atomic save (`save_offsets`): write the JSON to a temporary file in the same directory, flush,
fsync, `os.replace` it over the state file, then fsync the directory. A crash (SIGKILL, power
loss after the fsyncs) at any moment leaves either the old complete file or the new complete
file, never a mix; a stale temporary file may be left behind and is ignored (and removed by
a later save once it is older than a minute).

Record layout (`make_record` builds it, `parse_record` checks it)::

    {"format": 1, "robot": "desk", "offsets_rev": {"0": 12.5, "1": -3.25, ...},
     "home_position_m": [0.0, 0.0, 0.4], "wall_time_s": 1790000000.123}

`make_record` builds such a record, `parse_record` checks one and returns a `HomeRecord`.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

FORMAT_VERSION = 1
_STALE_TMP_S = 60.0


class HomingError(RuntimeError):
    """A state file that cannot be read or parsed, or a record for another robot / node set."""


def _tmp_prefix(path: Path) -> str:
    return f".{path.name}."


def save_offsets(path: str | os.PathLike[str], offsets: Mapping[str, Any]) -> None:
    """Atomically replace the JSON state file at `path` with `offsets`.

    Writes a temporary file in the same directory, flushes and fsyncs it, renames it over
    `path` (`os.replace`, atomic on POSIX) and fsyncs the directory so the rename is durable.
    Creates the parent directory if needed. Raises ValueError if `offsets` is not
    JSON-serialisable or holds NaN/inf (nothing is written then) and OSError if the directory
    cannot be written (the old file is untouched then).
    """
    target = Path(path)
    text = json.dumps(dict(offsets), allow_nan=False, indent=1, sort_keys=True) + "\n"
    data = text.encode("utf-8")
    directory = target.parent
    directory.mkdir(parents=True, exist_ok=True)
    _remove_stale_tmp(target)
    fd, tmp_name = tempfile.mkstemp(prefix=_tmp_prefix(target), suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
        raise
    _fsync_dir(directory)


def _fsync_dir(directory: Path) -> None:
    try:
        dfd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return  # platforms without directory fds: the rename is still atomic
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)


def _remove_stale_tmp(target: Path) -> None:
    """Remove temporary files left by a crashed save (only old ones: a single writer is assumed,
    the age guard keeps a concurrent writer's fresh temporary file alive)."""
    now = time.time()
    try:
        candidates = list(target.parent.glob(_tmp_prefix(target) + "*.tmp"))
    except OSError:
        return
    for p in candidates:
        with contextlib.suppress(OSError):
            if now - p.stat().st_mtime > _STALE_TMP_S:
                p.unlink()


def load_offsets(path: str | os.PathLike[str]) -> dict[str, Any] | None:
    """Read the JSON state file at `path`: the saved dict, or None if the file does not exist.

    Raises HomingError naming the file if it cannot be read, is not valid JSON or is not a
    JSON object (atomic saving makes a torn file impossible; this guards against hand edits
    and disk corruption).
    """
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise HomingError(f"{p}: cannot read the homing state file: {exc}") from exc
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise HomingError(f"{p}: homing state file is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise HomingError(f"{p}: homing state file must hold a JSON object")
    return data


@dataclass(frozen=True, slots=True)
class HomeRecord:
    """A checked homing record: robot name, offset per node id, home position, wall time."""

    robot: str
    offsets_rev: dict[int, float]
    home_position_m: tuple[float, float, float]
    wall_time_s: float


def make_record(
    robot: str,
    offsets_rev: Mapping[int, float],
    home_position_m: Sequence[float],
    wall_time_s: float | None = None,
) -> dict[str, Any]:
    """Build the JSON-able record to pass to `save_offsets` (wall time defaults to now).

    Raises ValueError on a non-finite offset or position or a position without 3 components.
    """
    offs: dict[str, float] = {}
    for node, off in offsets_rev.items():
        f = float(off)
        if not math.isfinite(f):
            raise ValueError(f"offset of node {node} must be finite, got {off!r}")
        offs[str(int(node))] = f
    pos = [float(c) for c in home_position_m]
    if len(pos) != 3 or not all(math.isfinite(c) for c in pos):
        raise ValueError(f"home_position_m must be 3 finite numbers, got {home_position_m!r}")
    return {
        "format": FORMAT_VERSION,
        "robot": robot,
        "offsets_rev": offs,
        "home_position_m": pos,
        "wall_time_s": time.time() if wall_time_s is None else float(wall_time_s),
    }


def parse_record(
    data: Mapping[str, Any],
    source: str,
    robot: str | None = None,
    node_ids: Sequence[int] | None = None,
) -> HomeRecord:
    """Check a loaded record and return it typed.

    With `robot` / `node_ids`, the record must belong to that robot and hold an offset for
    exactly those nodes. Raises HomingError naming `source` and the problem otherwise.
    """

    def bad(problem: str) -> HomingError:
        return HomingError(f"{source}: {problem}")

    if data.get("format") != FORMAT_VERSION:
        raise bad(f"unsupported format {data.get('format')!r} (expected {FORMAT_VERSION})")
    name = data.get("robot")
    if not isinstance(name, str):
        raise bad("'robot' must be a string")
    if robot is not None and name != robot:
        raise bad(f"record is for robot {name!r}, not {robot!r}")
    raw_offs = data.get("offsets_rev")
    if not isinstance(raw_offs, dict):
        raise bad("'offsets_rev' must be an object {node_id: turns}")
    offs: dict[int, float] = {}
    for k, v in raw_offs.items():
        try:
            node = int(k)
        except ValueError:
            raise bad(f"offsets_rev key {k!r} is not a node id") from None
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise bad(f"offsets_rev[{k}] must be a finite number, got {v!r}")
        offs[node] = float(v)
    if node_ids is not None and sorted(offs) != sorted(node_ids):
        raise bad(f"record holds nodes {sorted(offs)}, this robot has {sorted(node_ids)}")
    pos = data.get("home_position_m")
    if (
        not isinstance(pos, list)
        or len(pos) != 3
        or not all(
            isinstance(c, int | float) and not isinstance(c, bool) and math.isfinite(c) for c in pos
        )
    ):
        raise bad(f"'home_position_m' must be 3 finite numbers, got {pos!r}")
    wall = data.get("wall_time_s")
    if isinstance(wall, bool) or not isinstance(wall, int | float) or not math.isfinite(wall):
        raise bad(f"'wall_time_s' must be a finite number, got {wall!r}")
    return HomeRecord(
        robot=name,
        offsets_rev=offs,
        home_position_m=(float(pos[0]), float(pos[1]), float(pos[2])),
        wall_time_s=float(wall),
    )


def restored_pose_problem(
    pose_m: Sequence[float] | None,
    check_point: Any,
    power_up_m: Sequence[float] | None,
    far_m: float,
    state_file: str,
) -> str | None:
    """Why the pose a state file's offsets give at start-up is not to be believed, or None.

    `check_point(p)` is the workspace's rule (a reason, or None inside); a pose more than
    `far_m` from the configured power-up pose is suspect too (a drive that restarted counts
    from zero again, where the offsets were saved against other turns). The text names the
    pose, what is wrong with it and how to home again. Raises nothing.
    """

    def xyz(p: Sequence[float]) -> str:
        return "[" + ", ".join(f"{float(v):.4f}" for v in p) + "]"

    if pose_m is None:
        found = "give no valid pose with the drives' readings"
    else:
        problems = []
        outside = check_point(pose_m)
        if outside is not None:
            problems.append(f"outside the workspace ({outside})")
        if power_up_m is not None and math.dist(pose_m, power_up_m) > far_m:
            problems.append(
                f"{math.dist(pose_m, power_up_m):.3f} m from the power-up pose {xyz(power_up_m)}"
            )
        if not problems:
            return None
        found = f"put the effector at {xyz(pose_m)} m, " + " and ".join(problems)
    again = (
        f"; or remove {state_file} and restart to home at the power-up pose"
        if power_up_m is not None
        else ""
    )
    return (
        f"the homing offsets from {state_file} {found}: they are stale if a drive restarted "
        "since they were saved (its encoder counts from zero again). Support the effector at a "
        f"known pose and run `cablebot home X Y Z`{again}"
    )
