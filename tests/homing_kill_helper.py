"""Subprocess for the homing kill test: saves offsets records in a tight loop until killed.

Usage: python tests/homing_kill_helper.py STATE_FILE FIRST_SEQ [--unsafe]

Writes `version(seq)` for seq = FIRST_SEQ, FIRST_SEQ + 1, ... with `save_offsets`, prints
"ready" after the first save, then keeps saving until it is killed. `--unsafe` writes the file
in place (open, write in chunks, no rename) to show that the test detects a torn file.
"""

from __future__ import annotations

import sys
from typing import Any

from controller.service.offsets import save_offsets

PAD_CHARS = 100_000  # a big record keeps the write window wide


def version(seq: int) -> dict[str, Any]:
    """The record written as version `seq` (deterministic, so the test can recompute it)."""
    return {
        "format": 1,
        "robot": "kill-test",
        "seq": seq,
        "offsets_rev": {str(n): seq * 0.5 + n * 0.125 for n in range(4)},
        "home_position_m": [0.0, 0.0, 2.0],
        "wall_time_s": 1_700_000_000.0 + seq,
        "pad": chr(ord("a") + seq % 26) * PAD_CHARS,
    }


def unsafe_save(path: str, record: dict[str, Any]) -> None:
    """The naive way (for contrast): truncate and rewrite the file in place."""
    import json

    data = json.dumps(record, indent=1, sort_keys=True).encode()
    with open(path, "wb") as fh:
        for i in range(0, len(data), 8192):
            fh.write(data[i : i + 8192])
            fh.flush()


def main() -> None:
    path, seq = sys.argv[1], int(sys.argv[2])
    unsafe = "--unsafe" in sys.argv[3:]
    first = True
    while True:
        if unsafe:
            unsafe_save(path, version(seq))
        else:
            save_offsets(path, version(seq))
        if first:
            sys.stdout.write("ready\n")
            sys.stdout.flush()
            first = False
        seq += 1


if __name__ == "__main__":
    main()
