"""Measure cable stretch through the control loop on the simulated physical plant.

For each case (robot, plant EA, controller EA or rigid, tension source), home at the power-up
pose, move to each pose, settle, and print |truth - target| and |published pose - truth| in
millimetres. Real time (about a minute per case on the paper robot); run from the repository:

    .venv/bin/python tools/stretch_figures.py [paper|rigid|stretch|desk|ea20|measured ...]
"""

from __future__ import annotations

import sys
import uuid

from tests.service.test_loop_sim_stretch import StretchRig, desk_config, paper_config

PAPER_POSES = [(0, 0, 2), (20, 10, 2), (-30, -18, 1), (0, 0, 6), (35, 20, 3), (10, -5, 0.5)]
DESK_POSES = [(0.0, 0.0, 0.3), (0.2, -0.1, 0.15), (-0.3, 0.3, 0.6), (0.0, 0.0, 0.65)]


def run(label: str, cfg_fn, plant_ea, model_ea, poses, **kw) -> None:  # type: ignore[no-untyped-def]
    rig = StretchRig(cfg_fn(plant_ea, model_ea, f"stretch-fig-{uuid.uuid4().hex[:8]}", **kw))
    try:
        rig.arm()
        for p in poses:
            t = tuple(float(v) for v in p)
            e_t, e_p = rig.move_and_settle(t, timeout_s=300.0)
            print(
                f"{label:34s} {p!s:18s} truth-target {e_t * 1e3:9.3f} mm   "
                f"pose-truth {e_p * 1e3:9.3f} mm",
                flush=True,
            )
    finally:
        rig.close()


def main(which: list[str]) -> None:
    if "paper" in which:
        for ea in (1e6, 2e5):
            run(f"paper EA {ea:g} rigid model", paper_config, ea, None, PAPER_POSES)
            run(f"paper EA {ea:g} stretch model", paper_config, ea, ea, PAPER_POSES)
    if "rigid" in which:
        for ea in (1e6, 2e5):
            run(f"paper EA {ea:g} rigid model", paper_config, ea, None, PAPER_POSES)
    if "stretch" in which:
        for ea in (1e6, 2e5):
            run(f"paper EA {ea:g} stretch model", paper_config, ea, ea, PAPER_POSES)
    if "ea20" in which:
        for ea in (1e6, 2e5):
            for f in (0.8, 1.2):
                run(f"paper EA {ea:g} model EA x{f}", paper_config, ea, ea * f, PAPER_POSES)
    if "measured" in which:
        for ea in (1e6, 2e5):
            run(
                f"paper EA {ea:g} measured tensions",
                paper_config,
                ea,
                ea,
                PAPER_POSES,
                telemetry="cyclic",
                tensions="measured",
            )
    if "desk" in which:
        run("desk EA 1e5 rigid model", desk_config, 1e5, None, DESK_POSES)
        run("desk EA 1e5 stretch model", desk_config, 1e5, 1e5, DESK_POSES)


if __name__ == "__main__":
    main(sys.argv[1:] or ["paper", "desk"])
