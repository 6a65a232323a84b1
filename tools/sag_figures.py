"""Measure cable sag through the control loop on the simulated physical plant with heavy cables.

For each case (cable mass per metre, payload, the controller's cables heavy or massless), home
at the power-up pose, move to each pose, settle, and print |truth - target| and |published
pose - truth| in millimetres, or the controller's refusal. The paper robot with EA 4.5e5 N in
the plant and the controller. Real time (a minute or two per case); run from the repository:

    .venv/bin/python tools/sag_figures.py [loop|daemon|wrong ...]

`loop` runs the controller and the simulated drives in one process (the rig of
tests/service/test_loop_sim_sag.py); `daemon` runs `cablebot run` with its simulated drives in
its own process (`[sim] enabled`) and `cablebot sim` and `cablebot run` as two processes over
udp_multicast, the truth read on `<prefix>/sim/truth` over Zenoh; `wrong` the loop with the
controller's mass per metre 20 % off the plant's.
"""

from __future__ import annotations

import sys

from controller.core.commands import CommandRefused
from tests.service.test_loop_sim_sag import sag_config
from tests.service.test_loop_sim_stretch import StretchRig

POSES = [(0, 0, 2), (20, 10, 2), (-30, -18, 1), (0, 0, 6), (35, 20, 3), (10, -5, 0.5)]
CABLES = {"dyneema": 0.0083, "steel": 0.036}


def _line(label: str, p: tuple[float, ...], e_t: float, e_p: float) -> None:
    print(
        f"{label:34s} {p!s:16s} truth-target {e_t * 1e3:9.3f} mm   pose-truth {e_p * 1e3:9.3f} mm",
        flush=True,
    )


def run_loop(label: str, plant_per_m: float, model_per_m: float | None, payload_kg: float) -> None:
    rig = StretchRig(sag_config(plant_per_m, model_per_m, payload_kg))
    try:
        rig.arm()
        for p in POSES:
            t = tuple(float(v) for v in p)
            try:
                e_t, e_p = rig.move_and_settle(t, timeout_s=300.0)
            except CommandRefused as exc:
                if "on the leg to it" not in str(exc):
                    print(f"{label:34s} {p!s:16s} refused: {exc}", flush=True)
                    continue
                # the pose may be held where the straight leg to it is not: via the power-up
                # pose
                try:
                    rig.move_and_settle((0.0, 0.0, 2.0), timeout_s=300.0)
                    e_t, e_p = rig.move_and_settle(t, timeout_s=300.0)
                except CommandRefused as again:
                    print(f"{label:34s} {p!s:16s} refused: {again}", flush=True)
                    continue
            _line(label, p, e_t, e_p)
    finally:
        rig.close()


def run_daemon(
    label: str,
    per_m: float,
    model_per_m: float | None,
    payload_kg: float,
    sim_in_process: bool = False,
) -> None:
    import tempfile
    from pathlib import Path

    from tests.service.test_daemon_sim_stretch import SimDaemonRig

    with tempfile.TemporaryDirectory() as tmp:
        rig = SimDaemonRig(
            Path(tmp),
            4.5e5,
            4.5e5,
            plant_mass_kg_per_m=per_m,
            model_mass_kg_per_m=model_per_m,
            payload_kg=payload_kg,
            sim_in_process=sim_in_process,
        )
        try:
            rig.arm()
            for p in POSES:
                t = tuple(float(v) for v in p)
                try:
                    e_t, e_p = rig.move_and_settle(t, timeout_s=300.0)
                except AssertionError as exc:
                    if "on the leg to it" not in str(exc):
                        print(f"{label:34s} {p!s:16s} {str(exc).splitlines()[0][:200]}")
                        continue
                    try:  # via the power-up pose
                        rig.move_and_settle((0.0, 0.0, 2.0), timeout_s=300.0)
                        e_t, e_p = rig.move_and_settle(t, timeout_s=300.0)
                    except AssertionError as again:
                        print(f"{label:34s} {p!s:16s} {str(again).splitlines()[0][:200]}")
                        continue
                _line(label, p, e_t, e_p)
        finally:
            rig.close()


def main(which: list[str]) -> None:
    for name, per_m in CABLES.items():
        for kg in (5.0, 20.0):
            if "loop" in which:
                run_loop(f"loop {name} {kg:g} kg today", per_m, None, kg)
                run_loop(f"loop {name} {kg:g} kg sag model", per_m, per_m, kg)
            if "daemon" in which:
                if kg == 5.0:
                    run_daemon(f"daemon+sim {name} {kg:g} kg today", per_m, None, kg)
                run_daemon(f"daemon+sim {name} {kg:g} kg sag model", per_m, per_m, kg)
                run_daemon(f"daemon(sim) {name} {kg:g} kg sag model", per_m, per_m, kg, True)
            if "wrong" in which and kg == 5.0:
                for f in (0.8, 1.2):
                    run_loop(f"loop {name} 5 kg model x{f:g}", per_m, per_m * f, kg)


if __name__ == "__main__":
    main(sys.argv[1:] or ["loop"])
