"""Writing calibrated anchors into a configuration's TOML text, keeping everything else.

Pure: text in, text out; no I/O.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Mapping
from typing import Any

import numpy as np

from controller.core.calibration_samples import CalibrationError

_HEADER_RE = re.compile(r"^\s*\[")
_REELS_RE = re.compile(r"^\s*\[\[\s*reels\s*\]\]")
_ANCHOR_RE = re.compile(r"^(\s*anchor_m\s*=\s*)\[([^\]\n]*)\](.*)$", re.DOTALL)
_ANCHOR_KEY_RE = re.compile(r"^\s*anchor_m\s*=")


def format_metres(v: float) -> str:
    """A coordinate for the TOML file: micrometre resolution, no trailing zeros (``-0.5``)."""
    s = f"{round(float(v), 6):.6f}".rstrip("0")
    s = s + "0" if s.endswith(".") else s
    return "0.0" if s in ("-0.0", "0.0") else s


def replace_anchor_values(text: str, anchors_m: Any, source: str) -> str:
    """The TOML `text` with each ``[[reels]]`` table's ``anchor_m = [x, y, z]`` values replaced.

    Everything else (comments, order, the rest of each line) is kept byte for byte. Raises
    CalibrationError when `text` is not valid TOML, a reel's ``anchor_m`` is not one line of
    a ``[[reels]]`` table, the number of reels differs, or the edited text would parse to
    anything but the original with the new anchors.
    """
    new = np.asarray(anchors_m, dtype=np.float64)
    try:
        before = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(f"{source}: not valid TOML: {exc}") from exc
    lines = text.splitlines(keepends=True)
    reel = -1
    in_reels = False
    found: list[int] = []
    for idx, line in enumerate(lines):
        if _HEADER_RE.match(line):
            in_reels = bool(_REELS_RE.match(line))
            if in_reels:
                reel += 1
            continue
        if not (in_reels and _ANCHOR_KEY_RE.match(line)):
            continue
        m = _ANCHOR_RE.match(line)
        if m is None:
            raise CalibrationError(
                f"{source} line {idx + 1}: reels[{reel}].anchor_m must be written on one line "
                "as anchor_m = [x, y, z] to be replaced"
            )
        if reel >= new.shape[0]:
            raise CalibrationError(f"{source}: more [[reels]] tables than {new.shape[0]} anchors")
        values = ", ".join(format_metres(v) for v in new[reel])
        lines[idx] = f"{m.group(1)}[{values}]{m.group(3)}"
        found.append(reel)
    if found != list(range(new.shape[0])):
        raise CalibrationError(
            f"{source}: found anchor_m lines for reels {found}, expected one in each of "
            f"{new.shape[0]} [[reels]] tables"
        )
    out = "".join(lines)
    try:
        after = tomllib.loads(out)
    except tomllib.TOMLDecodeError as exc:  # pragma: no cover - the regex keeps it valid
        raise CalibrationError(f"{source}: the edited text is not valid TOML: {exc}") from exc
    expected = _with_anchors(before, [[float(format_metres(v)) for v in row] for row in new])
    if after != expected:
        raise CalibrationError(f"{source}: editing the anchor lines changed more than the anchors")
    return out


def _with_anchors(data: Mapping[str, Any], anchors: list[list[float]]) -> dict[str, Any]:
    out = dict(data)
    reels = data.get("reels")
    if not isinstance(reels, list) or len(reels) != len(anchors):
        raise CalibrationError(f"the configuration has no {len(anchors)} [[reels]] tables")
    out["reels"] = [{**r, "anchor_m": a} for r, a in zip(reels, anchors, strict=True)]
    return out
