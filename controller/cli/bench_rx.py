"""Receive-path throughput of the driver layer (used by `cablebot bench`; runnable alone).

`python -m controller.cli.bench_rx [--frames N]` prints two figures, each on one core:

* pure decode: `cansimple.decode` on pre-built (id, bytes) pairs;
* full receive path: `ODriveReels.poll()` draining a python-can `virtual` bus pre-filled with
  encoder (90 %) and heartbeat (10 %) frames for 4 axes: python-can Message objects, the bus's
  queue, decode, reading update and stamping.

A 1 Mbit/s CAN bus carries at most about 8,000 frames/s; the requirement is >= 20,000 frames/s.
"""

from __future__ import annotations

import argparse
import time
import uuid
from collections.abc import Sequence

import can

from drivers.odrive import cansimple as cs
from drivers.odrive.driver import ODriveReels


def _frames(n: int) -> list[cs.Frame]:
    out: list[cs.Frame] = []
    for i in range(n):
        node = i % 4
        if i % 10:
            out.append(cs.encode_encoder_estimates(node, i * 1e-3, 1.0))
        else:
            out.append(cs.encode_heartbeat(node, 0, cs.AxisState.CLOSED_LOOP_CONTROL))
    return out


def pure_decode_rate(n_frames: int = 100_000) -> float:
    """Frames per second through `cansimple.decode` alone."""
    frames = [(a, d) for a, d, _ in _frames(n_frames)]
    decode = cs.decode
    t0 = time.perf_counter()
    for arb_id, data in frames:
        decode(arb_id, data)
    return n_frames / (time.perf_counter() - t0)


def poll_rate(n_frames: int = 50_000) -> float:
    """Frames per second through `ODriveReels.poll()` on a pre-filled virtual bus.

    Raises RuntimeError if not every frame was received and decoded cleanly.
    """
    channel = f"rx-bench-{uuid.uuid4().hex}"
    rx = can.Bus(interface="virtual", channel=channel)
    tx = can.Bus(interface="virtual", channel=channel)
    try:
        for arb_id, data, _ in _frames(n_frames):
            tx.send(can.Message(arbitration_id=arb_id, data=data, is_extended_id=False))
        driver = ODriveReels(rx, range(4), max_frames_per_poll=256)
        handled = 0
        t0 = time.perf_counter()
        while True:
            got = driver.poll()
            if got == 0:
                break
            handled += got
        elapsed = time.perf_counter() - t0
        if handled != n_frames or driver.stats.decode_errors:
            raise RuntimeError(f"handled {handled}/{n_frames}, stats {driver.stats}")
        return handled / elapsed
    finally:
        rx.shutdown()
        tx.shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    """Print the two receive-path figures."""
    p = argparse.ArgumentParser(prog="python -m controller.cli.bench_rx", description=__doc__)
    p.add_argument("--frames", type=int, default=50_000)
    args = p.parse_args(argv)
    print(f"pure decode:                    {pure_decode_rate(2 * args.frames):>10,.0f} frames/s")
    print(f"ODriveReels.poll (virtual bus): {poll_rate(args.frames):>10,.0f} frames/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
