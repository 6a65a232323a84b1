"""Measure cable sag through the control loop on the simulated physical plant with heavy cables.

For each case (cable mass per metre, payload, the controller's cables heavy or massless), home
at the power-up pose, move to each pose, settle, and print |truth - target| and |published
pose - truth| in millimetres, or the controller's refusal. The paper robot with EA 4.5e5 N in
the plant and the controller. Real time (a minute or two per case); run from the repository:

    PYTHONPATH=. .venv/bin/python tools/sag_figures.py [loop|daemon|dyneema|steel|wrong|5kg|20kg]

`loop` runs the controller and the simulated drives in one process (the rig of
tests/service/test_loop_sim_sag.py); `daemon` runs `cablebot run` with its simulated drives in
its own process (`[sim] enabled`) and `cablebot sim` and `cablebot run` as two processes over
udp_multicast, the truth read on `<prefix>/sim/truth` over Zenoh; `wrong` the loop with the
controller's mass per metre 20 % off the plant's; `dyneema` or `steel` the daemon with that
cable only, `5kg` or `20kg` that payload only.
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


def _routes(at: tuple[float, ...], t: tuple[float, ...]) -> list[list[tuple[float, ...]]]:
    """Ways from `at` to a pose `t` whose straight leg is refused: via the power-up pose, or
    low (0.5 m) down from `at`, through (10, -5, 0.5) and up under the target."""
    low = [(at[0], at[1], 0.5), (10.0, -5.0, 0.5), (t[0], t[1], 0.5)]
    return [[], [(0.0, 0.0, 2.0)], [p for p in low if p not in (at, t)]]


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

    def refusal(exc: AssertionError) -> str:
        arg = exc.args[0] if exc.args else ""
        if isinstance(arg, tuple) and isinstance(arg[0], dict) and "error" in arg[0]:
            return f"refused: {arg[0]['error']}"
        return str(exc).splitlines()[0][:300]

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
            at: tuple[float, ...] = (0.0, 0.0, 2.0)
            for p in POSES:
                t = tuple(float(v) for v in p)
                why = ""
                for route in _routes(at, t):
                    try:
                        for via in route:
                            rig.move_and_settle(via, timeout_s=300.0)
                            at = via
                        e_t, e_p = rig.move_and_settle(t, timeout_s=300.0)
                    except AssertionError as exc:
                        why = why or refusal(exc)  # the direct leg's reason
                        if "on the leg to it" in why:
                            continue
                        break
                    _line(label + (f" via {route}" if route else ""), p, e_t, e_p)
                    at, why = t, ""
                    break
                if why:
                    print(f"{label:34s} {p!s:16s} {why}", flush=True)
        finally:
            rig.close()


def main(which: list[str]) -> None:
    kgs = [kg for kg in (5.0, 20.0) if f"{kg:g}kg" in which] or [5.0, 20.0]
    for name, per_m in CABLES.items():
        for kg in kgs:
            if "loop" in which:
                run_loop(f"loop {name} {kg:g} kg today", per_m, None, kg)
                run_loop(f"loop {name} {kg:g} kg sag model", per_m, per_m, kg)
            if "daemon" in which or name in which:
                run_daemon(f"daemon(sim) {name} {kg:g} kg sag model", per_m, per_m, kg, True)
                run_daemon(f"daemon+sim {name} {kg:g} kg sag model", per_m, per_m, kg)
            if "wrong" in which and kg == 5.0:
                for f in (0.8, 1.2):
                    run_loop(f"loop {name} 5 kg model x{f:g}", per_m, per_m * f, kg)


if __name__ == "__main__":
    main(sys.argv[1:] or ["loop"])
