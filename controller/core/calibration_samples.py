"""Calibration samples: the CSV the `cablebot calibrate collect` run writes and `calibrate`
reads (the format is described in `controller.core.calibration`), and the error both raise.

Pure: numpy and the csv module; no I/O (text in, text out).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

POSE_COLUMNS = ("x_m", "y_m", "z_m")
"""The CSV columns of the pose the controller believed."""


class CalibrationError(ValueError):
    """Samples or a configuration from which no calibration can be made; the reason says why."""


def rev_column(node_id: int) -> str:
    """The CSV column of a reel's motor turns, e.g. ``node_3_rev``."""
    return f"node_{int(node_id)}_rev"


def samples_header(node_ids: Sequence[int]) -> list[str]:
    """The CSV header: one ``node_<id>_rev`` column per reel (cable order), then x_m, y_m, z_m."""
    return [rev_column(n) for n in node_ids] + list(POSE_COLUMNS)


def samples_preamble(robot: str, node_ids: Sequence[int], when: str) -> str:
    """The comment lines that open a samples file (each starts with ``#``, ends with newline)."""
    ids = ", ".join(str(int(n)) for n in node_ids)
    return (
        f"# cablebot calibration samples: robot {robot!r}, nodes {ids}, recorded {when}\n"
        "# one row per pose: each reel's motor position (node_<id>_rev, motor turns as the\n"
        "# drive reports it) and the pose the controller believed (x_m, y_m, z_m, metres)\n"
    )


def format_sample_row(motor_rev: Sequence[float], position_m: Sequence[float]) -> list[str]:
    """One CSV row (full float precision). Raises ValueError on a non-finite value."""
    values = [float(v) for v in motor_rev] + [float(v) for v in position_m]
    if len(position_m) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"a sample needs finite motor turns and 3 finite pose values: {values}")
    return [repr(v) for v in values]


@dataclass(frozen=True, slots=True)
class Samples:
    """K recorded poses: motor turns (K, N) in cable order and the believed poses (K, 3)."""

    node_ids: tuple[int, ...]
    motor_rev: FloatArray
    believed_m: FloatArray

    @property
    def n_poses(self) -> int:
        """Number of recorded poses (K)."""
        return int(self.motor_rev.shape[0])


def parse_samples(text: str, source: str, node_ids: Sequence[int]) -> Samples:
    """Read samples CSV text (format in the module docstring) for reels `node_ids` (cable order).

    Raises CalibrationError naming `source` and the line for: no header, a missing, unknown or
    repeated column, a row with the wrong number of cells, a value that is not a finite
    number, or no rows at all.
    """
    ids = tuple(int(n) for n in node_ids)
    wanted = samples_header(ids)
    header: list[str] | None = None
    index: list[int] = []
    rev_rows: list[list[float]] = []
    pose_rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        cells = [c.strip() for c in next(csv.reader(io.StringIO(stripped)))]
        if header is None:
            header = cells
            seen: set[str] = set()
            for name in cells:
                if name in seen:
                    raise CalibrationError(f"{source} line {lineno}: column {name!r} repeated")
                seen.add(name)
                if name not in wanted:
                    raise CalibrationError(
                        f"{source} line {lineno}: unknown column {name!r} "
                        f"(expected {', '.join(wanted)})"
                    )
            missing = [w for w in wanted if w not in seen]
            if missing:
                raise CalibrationError(
                    f"{source} line {lineno}: missing column(s) {', '.join(missing)} "
                    f"(the configuration's reels are nodes {', '.join(map(str, ids))})"
                )
            index = [cells.index(w) for w in wanted]
            continue
        if len(cells) != len(header):
            raise CalibrationError(
                f"{source} line {lineno}: {len(cells)} values, the header has {len(header)}"
            )
        values: list[float] = []
        for j in index:
            try:
                v = float(cells[j])
            except ValueError:
                raise CalibrationError(
                    f"{source} line {lineno}: {header[j]} = {cells[j]!r} is not a number"
                ) from None
            if not math.isfinite(v):
                raise CalibrationError(
                    f"{source} line {lineno}: {header[j]} = {cells[j]} is not finite"
                )
            values.append(v)
        rev_rows.append(values[: len(ids)])
        pose_rows.append(values[len(ids) :])
    if header is None:
        raise CalibrationError(f"{source}: no header line (expected {', '.join(wanted)})")
    if not rev_rows:
        raise CalibrationError(f"{source}: no samples after the header")
    return Samples(
        node_ids=ids,
        motor_rev=np.array(rev_rows, dtype=np.float64),
        believed_m=np.array(pose_rows, dtype=np.float64),
    )
