"""The Hangprinters through the daemon: `cablebot run` on config/hangprinter-v4.toml (and
config/hangprinter-5.toml), its simulated ODrives and the physical plant (a 1 kg effector on
lines of EA 20 kN) in the daemon's process. It homes at the power-up pose and arms itself;
after moves through the pyramid (near the bed, high up, off-centre) and a path, the plant's
truth (read on `<prefix>/sim/truth`) is within 0.1 mm of the target and the published pose
within 0.1 mm of the truth; a target outside the pyramid, above the highest anchor's reach,
under the bed or beyond the print radius is refused by its rule.
"""

from __future__ import annotations

import json
import math
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from controller.service.simulated import TRUTH_KEY
from tests.daemon_procs import CABLEBOT, Proc, write_config, zenoh_session, zquery

REPO = Path(__file__).resolve().parents[2]
HP4 = REPO / "config" / "hangprinter-v4.toml"
HP5 = REPO / "config" / "hangprinter-5.toml"

Vec3 = tuple[float, float, float]


class HangprinterRig:
    """`cablebot run` on a copy of a Hangprinter file (own virtual channel and Zenoh port) and
    a client session following its pose and the simulator's truth."""

    def __init__(self, tmp_path: Path, robot: Path = HP4) -> None:
        path, info = write_config(
            tmp_path,
            {"interface": "virtual", "channel": f"hp-{uuid.uuid4().hex[:8]}"},
            base=robot,
            rate_hz=500.0,
            sim_enabled=True,
            sim={"watchdog_timeout_s": 4.0},
            # a shared, loaded machine: a starved thread must not fault a measurement of where
            # the effector rests (the faults themselves are tested elsewhere)
            faults={"stale_timeout_s": 3.0, "heartbeat_timeout_s": 3.0, "tracking_max_m": 0.5},
        )
        self.prefix = str(info["prefix"])
        self.daemon = Proc([*CABLEBOT, "run", "--config", str(path), "--status-every", "0"], "run")
        self.session: Any = None
        self._lock = threading.Lock()
        self._pose: dict[str, Any] | None = None
        self._truth: dict[str, Any] | None = None
        try:
            self.session = zenoh_session(str(info["endpoint"]), 60.0)
            self.session.declare_subscriber(f"{self.prefix}/pose", self._on_pose)
            self.session.declare_subscriber(f"{self.prefix}/{TRUTH_KEY}", self._on_truth)
        except BaseException:
            self.close()
            raise

    def _on_pose(self, sample: Any) -> None:
        with self._lock:
            self._pose = json.loads(sample.payload.to_bytes())

    def _on_truth(self, sample: Any) -> None:
        with self._lock:
            self._truth = json.loads(sample.payload.to_bytes())

    def latest(self) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
        with self._lock:
            return self._pose, self._truth

    def wait(self, pred: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not pred():
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"timed out waiting for {what}: {self.latest()}\n" + self.log()
                )
            time.sleep(0.02)

    def log(self) -> str:
        return self.daemon.log()

    def state(self) -> str | None:
        pose = self.latest()[0]
        return None if pose is None else str(pose["state"])

    def command(self, verb: str, payload: dict[str, Any]) -> dict[str, Any]:
        return zquery(self.session, f"{self.prefix}/cmd/{verb}", payload, 10.0)

    def settle(self, target: Sequence[float], timeout_s: float = 120.0) -> tuple[float, float]:
        """Wait for HOLDING and the truth still (within 2 um for 1.5 s); (|truth - target|,
        |published pose - truth|) in metres."""
        deadline = time.monotonic() + timeout_s
        anchor: Vec3 | None = None
        since = time.monotonic()
        while True:
            assert time.monotonic() < deadline, f"not at rest at {target}\n{self.log()}"
            pose, truth = self.latest()
            assert pose is not None and truth is not None
            assert pose["state"] not in ("FAULT", "ESTOPPED"), (pose, self.log())
            p = tuple(truth["position_m"])
            holding = pose["state"] == "HOLDING" and pose["valid"]
            if not holding or anchor is None or math.dist(p, anchor) > 2e-6:
                anchor = (float(p[0]), float(p[1]), float(p[2]))
                since = time.monotonic()
            elif time.monotonic() - since >= 1.5:
                break
            time.sleep(0.05)
        time.sleep(0.2)  # a pose published after the rest began
        pose, truth = self.latest()
        assert pose is not None and truth is not None
        return (
            math.dist(truth["position_m"], target),
            math.dist(pose["position_m"], truth["position_m"]),
        )

    def close(self) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None
        self.daemon.terminate(10.0)


def test_hangprinter_v4_flies_its_pyramid_to_a_tenth_of_a_millimetre(tmp_path: Path) -> None:
    rig = HangprinterRig(tmp_path)
    try:
        rig.wait(lambda: rig.state() == "HOLDING", 90.0, "HOLDING (homed and armed by itself)")
        rig.wait(lambda: rig.latest()[1] is not None, 30.0, "the truth")
        errors = []
        for target in [(0.3, -0.2, 0.05), (-0.4, 0.3, 0.6), (0.1, 0.1, 1.5), (0.0, -0.5, 0.3)]:
            reply = rig.command("move", {"position_m": list(target), "speed_mps": 0.3})
            assert "error" not in reply, (reply, rig.log())
            errors.append(rig.settle(target))
        path = [(0.2, 0.2, 0.4), (-0.2, 0.2, 0.5), (-0.2, -0.2, 0.6), (0.2, -0.2, 0.7)]
        reply = rig.command("path", {"points_m": [list(p) for p in path], "speed_mps": 0.2})
        assert "error" not in reply, (reply, rig.log())
        errors.append(rig.settle(path[-1]))
        for err_target, err_pose in errors:
            assert err_target < 1e-4, errors
            assert err_pose < 1e-4, errors
        # refusals name their rule
        for target, words in [
            ((0.9, 0.0, 0.2), "outside the anchors' hull (the face of cables 1, 2, 4)"),
            ((0.0, 0.0, 2.0), "above the highest anchor minus top_margin_m (1.9 m)"),
            ((0.0, 0.0, -0.05), "below the floor (floor_z_m 0 m)"),
            ((0.0, -0.95, 0.1), "beyond print_radius_m (0.9 m)"),
        ]:
            reply = rig.command("move", {"position_m": list(target)})
            assert words in str(reply.get("error", "")), (target, reply)
        assert rig.state() == "HOLDING"
    finally:
        rig.close()


def test_the_five_anchor_hangprinter_too(tmp_path: Path) -> None:
    rig = HangprinterRig(tmp_path, HP5)
    try:
        rig.wait(lambda: rig.state() == "HOLDING", 90.0, "HOLDING (homed and armed by itself)")
        rig.wait(lambda: rig.latest()[1] is not None, 30.0, "the truth")
        for target in [(0.6, -0.5, 0.05), (-0.5, 0.6, 0.8), (0.1, -0.1, 1.6)]:
            reply = rig.command("move", {"position_m": list(target), "speed_mps": 0.3})
            assert "error" not in reply, (reply, rig.log())
            err_target, err_pose = rig.settle(target)
            assert err_target < 1e-4 and err_pose < 1e-4, (target, err_target, err_pose)
        reply = rig.command("move", {"position_m": [0.9, 0.9, 0.1]})
        assert "beyond print_radius_m (1.2 m)" in str(reply.get("error", "")), reply
    finally:
        rig.close()
