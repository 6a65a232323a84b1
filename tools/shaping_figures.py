"""Measure the effector's residual vibration with and without input shaping, on the simulated
physical plant through the real control step (`controller.cli.bench.vibration.PlantRig`): the
figures of docs/shaping.md. Deterministic (a hand-moved clock, no threads); run from the
repository:

    .venv/bin/python tools/shaping_figures.py moves paper [--quick]   # 25 poses x 6 directions
    .venv/bin/python tools/shaping_figures.py moves desk               # 9 poses x 6 directions
    .venv/bin/python tools/shaping_figures.py paths                    # the square, the vase
    .venv/bin/python tools/shaping_figures.py vertical                 # one move, drives, ticks
    .venv/bin/python tools/shaping_figures.py offset paper --mass 5 --pose=0,-9,4.5 --direction z+ \
        --model-error 0.7                                              # the wrong EA's rest offset

`moves`: from each pose a rest-to-rest move in +-x, +-y, +-z (2 m on the paper robot, 0.2 m
on the desk rig, halved until the target and the leg are allowed), for each payload, with the
shaper off and on (`--type`, default the configuration's default), the controller's model of
the cables exact and 30 % off (EA x 0.7 and x 1.3: its frequencies 16 % low and 14 % high).
Per move it prints the residual vibration (the largest distance of the truth from its rest
point over the 3 s after the move ends), the time the move took and the shaper's delay at the
end. The summary gives, per pose, the smallest ratio unshaped / shaped over its moves, and
the smallest and the median of those over the poses. `--pose=X,Y,Z`, `--direction` (x+, z-,
...), `--model-error` and `--mass` (each repeatable) select a part of the matrix;
`--passes` sets the shaped runs' `[shaper] passes`; `--frequency-scale` sets their
`[shaper] frequency_scale` (the shaper's frequencies
off on purpose, the stretch model untouched); `--speed` the moves' speed (m/s).

`offset`: where the lengths the controller commands bring the effector to rest, against the
set-point, along a move whose model EA is off (`--model-error`): the rest offset, its slope
and its curvature (the wrong stretch seen by the plant as a different, curved move).

`paths`: the repository's square (`config/square-path.csv`, paper robot, 5 kg) and the first two
layers of `tests/data/vase.gcode.gz` (desk rig): the largest distance of the set-point and of
the truth from the programmed path, shaped and unshaped.

`vertical`: the paper robot's 2 m vertical move from (0, 0, 2) m at 1 m/s with 5 and 20 kg,
on ideal drives and on the simulated ODrive's position loop, and with the loop's ticks uneven.
"""

from __future__ import annotations

import argparse
import gzip
import itertools
import math
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from controller.cli.bench.vibration import (  # noqa: E402
    DESK_EA_N,
    PAPER_EA_N,
    PlantRig,
    robot_config,
    robot_data,
)
from controller.core.motion.shaper import DEFAULT_SHAPER_TYPE  # noqa: E402

Vec3 = tuple[float, float, float]

PAPER_POSES: list[Vec3] = [
    (x, y, (0.5, 1.5, 2.5, 3.5, 4.5)[(i + 2 * j) % 5])
    for i, x in enumerate((-30.0, -15.0, 0.0, 15.0, 30.0))
    for j, y in enumerate((-18.0, -9.0, 0.0, 9.0, 18.0))
]
DESK_POSES: list[Vec3] = [
    (x, y, (0.2, 0.35, 0.5)[(i + j) % 3])
    for i, x in enumerate((-0.25, 0.0, 0.25))
    for j, y in enumerate((-0.25, 0.0, 0.25))
]
DIRECTIONS: list[Vec3] = [
    (1.0, 0.0, 0.0),
    (-1.0, 0.0, 0.0),
    (0.0, 1.0, 0.0),
    (0.0, -1.0, 0.0),
    (0.0, 0.0, 1.0),
    (0.0, 0.0, -1.0),
]
ROBOTS: dict[str, dict[str, Any]] = {
    "paper": {
        "poses": PAPER_POSES,
        "masses": (5.0, 20.0),
        "ea": PAPER_EA_N,
        "length_m": 2.0,
        "speed_mps": 1.0,
        "max_tension_n": 2000.0,
    },
    "desk": {
        "poses": DESK_POSES,
        "masses": (0.5,),
        "ea": DESK_EA_N,
        "length_m": 0.2,
        "speed_mps": 0.3,
        "max_tension_n": None,
    },
}
MODEL_ERRORS = (1.0, 0.7, 1.3)


def _allowed(cfg: Any, start: Vec3, target: Vec3) -> bool:
    """True when the leg from `start` to `target` keeps the workspace and the tension rule."""
    from controller.core.workspace import Workspace
    from controller.service.config import tension_check

    ws = Workspace.from_limits(cfg.limits, cfg.geometry)
    if ws.check_target(target) is not None or ws.check_segment(start, target) is not None:
        return False
    check = tension_check(cfg.payload, cfg.tension, cfg.geometry)
    return check.path_failure([target], start, 0.05) is None


def target_for(cfg: Any, start: Vec3, direction: Vec3, length_m: float) -> Vec3 | None:
    """The move's target: `length_m` along `direction`, halved (3 times at most) until allowed."""
    for k in range(4):
        d = length_m / 2**k
        t = (start[0] + d * direction[0], start[1] + d * direction[1], start[2] + d * direction[2])
        if _allowed(cfg, start, t):
            return t
    return None


DIRECTION_NAMES = {"x+": 0, "x-": 1, "y+": 2, "y-": 3, "z+": 4, "z-": 5}


@dataclass(frozen=True)
class Selection:
    """A part of the `moves` matrix: poses, directions, model errors and payloads (None: all
    of the robot's), and the shaped runs' frequency scale."""

    poses: list[Vec3] | None = None
    directions: list[Vec3] | None = None
    errors: tuple[float, ...] = MODEL_ERRORS
    masses: tuple[float, ...] | None = None
    frequency_scale: float = 1.0
    speed_mps: float | None = None
    passes: int = 1


def moves(robot: str, kind: str, quick: bool, sel: Selection | None = None) -> None:
    """The residual-vibration matrix of `robot` (module docstring), or the part `sel`."""
    sel = Selection() if sel is None else sel
    spec = ROBOTS[robot]
    data = robot_data(robot)
    poses = sel.poses or (spec["poses"][:3] if quick else spec["poses"])
    shaper: dict[str, Any] = {"type": kind}
    if sel.frequency_scale != 1.0:
        shaper["frequency_scale"] = sel.frequency_scale
    if sel.passes != 1:
        shaper["passes"] = sel.passes
    # ratios[(mass, error)][pose] = list of unshaped / shaped over the directions
    ratios: dict[tuple[float, float], dict[int, list[float]]] = {}
    gains: list[tuple[float, float]] = []
    t0 = time.monotonic()
    for mass in sel.masses or spec["masses"]:
        for pi, start in enumerate(poses):
            for direction in sel.directions or DIRECTIONS:
                target = None
                for err in sel.errors:
                    res = {}
                    for shaped in (False, True):
                        cfg = robot_config(
                            data,
                            mass_kg=mass,
                            plant_ea_n=spec["ea"],
                            model_ea_n=spec["ea"] * err,
                            start_m=start,
                            shaper=shaper if shaped else None,
                            max_tension_n=spec["max_tension_n"],
                        )
                        if target is None:
                            target = target_for(cfg, start, direction, spec["length_m"])
                            if target is None:
                                break
                        rig = PlantRig(cfg)
                        res[shaped] = rig.move(target, sel.speed_mps or spec["speed_mps"])
                    if target is None:
                        print(f"{robot} {mass:g} kg {start} {direction}: no allowed move")
                        break
                    off, on = res[False], res[True]
                    ratio = off.residual_m / max(on.residual_m, 1e-9)
                    ratios.setdefault((mass, err), {}).setdefault(pi, []).append(ratio)
                    if err == 1.0:
                        gains.append((on.duration_s - off.duration_s, on.shaper_delay_s))
                    print(
                        f"{robot} {mass:4g} kg EA x{err:g} from {_p(start)} to {_p(target)}: "
                        f"residual {off.residual_m * 1e3:9.3f} mm unshaped, "
                        f"{on.residual_m * 1e3:8.4f} mm shaped ({ratio:7.1f}x); "
                        f"{off.duration_s:.3f} s -> {on.duration_s:.3f} s "
                        f"(delay {on.shaper_delay_s:.3f} s); off line {on.off_line_m * 1e6:.2f} um",
                        flush=True,
                    )
    scale = f", frequency scale {sel.frequency_scale:g}" if sel.frequency_scale != 1.0 else ""
    scale += f", {sel.passes} passes" if sel.passes != 1 else ""
    print(f"\n{robot}, shaper {kind}{scale}, {time.monotonic() - t0:.0f} s")
    print(
        "| payload | model EA | worst pose: smallest ratio | median over poses of the "
        "smallest ratio | poses |"
    )
    print("| --- | --- | --- | --- | --- |")
    for (mass, err), per_pose in sorted(ratios.items()):
        worst = [min(v) for v in per_pose.values()]
        print(
            f"| {mass:g} kg | x{err:g} | {min(worst):.1f}x | {statistics.median(worst):.1f}x "
            f"| {len(worst)} |"
        )
    if gains:
        over = max(g - d for g, d in gains)
        lo = min(g for g, _ in gains)
        hi = max(g for g, _ in gains)
        print(
            f"time shaping adds to a move: {lo:.3f}..{hi:.3f} s; largest excess over the shaper's "
            f"delay at the end {over * 1e3:.1f} ms"
        )


def offset(robot: str, sel: Selection, steps: int = 20) -> None:
    """For each selected payload, pose, direction and model error: where the lengths the
    controller commands bring the effector to rest, against the set-point, at `steps` + 1
    set-points along the move at rest (no acceleration). The plant starts at rest at the pose
    (homed there: no offset at the start)."""
    import numpy as np

    from controller.core import kinematics
    from controller.core.plant import equilibrium

    spec = ROBOTS[robot]
    data = robot_data(robot)
    for mass in sel.masses or spec["masses"]:
        for start in sel.poses or spec["poses"]:
            for direction in sel.directions or DIRECTIONS:
                for err in sel.errors:
                    cfg = robot_config(
                        data,
                        mass_kg=mass,
                        plant_ea_n=spec["ea"],
                        model_ea_n=spec["ea"] * err,
                        start_m=start,
                        shaper=None,
                        max_tension_n=spec["max_tension_n"],
                    )
                    target = target_for(cfg, start, direction, spec["length_m"])
                    if target is None:
                        print(f"{robot} {mass:g} kg {_p(start)} {_p(direction)}: no allowed move")
                        continue
                    rig = PlantRig(cfg)
                    ctl = rig.ctl
                    assert ctl.tension is not None
                    params = rig.plant.plant.params
                    home_l0 = rig.plant.plant.unstretched_m

                    def commanded(p: Vec3, cfg: Any = cfg, ctl: Any = ctl) -> list[float]:
                        t = ctl.tension.solve(p).tensions_n
                        lengths = kinematics.ipk_point(cfg.geometry, p)
                        return list(ctl.cables.commanded_lengths_m(lengths, t))

                    home = commanded(start)
                    span = math.dist(start, target)
                    s_m = np.linspace(0.0, span, steps + 1)
                    off = []
                    for s in s_m:
                        p = tuple(start[i] + s / span * (target[i] - start[i]) for i in range(3))
                        c = commanded(p)
                        l0 = [a + (b - b0) for a, b, b0 in zip(home_l0, c, home, strict=True)]
                        rest = equilibrium(params, l0, p).position_m
                        off.append([rest[i] - p[i] for i in range(3)])
                    o = np.array(off)
                    along = o @ (np.subtract(target, start) / span)
                    slope = np.gradient(along, s_m)
                    curve = np.gradient(slope, s_m)
                    unit = np.subtract(target, start) / span
                    across = float(np.linalg.norm(o[-1] - along[-1] * unit))
                    print(
                        f"{robot} {mass:g} kg EA x{err:g} from {_p(start)} to {_p(target)}: "
                        f"rest offset along the move {along[-1] * 1e3:+.3f} mm at the end "
                        f"(across {across * 1e3:.3f} mm), "
                        f"slope {slope.min():+.3f}..{slope.max():+.3f}, "
                        f"curvature {curve.min():+.3f}..{curve.max():+.3f} /m"
                    )
                    for k in range(0, steps + 1, max(1, steps // 5)):
                        print(
                            f"    {s_m[k]:5.2f} m: offset {along[k] * 1e3:+9.3f} mm, "
                            f"slope {slope[k]:+.3f}, curvature {curve[k]:+.3f} /m"
                        )


def vertical(kind: str) -> None:
    """The paper robot's 2 m vertical move from (0, 0, 2) m at 1 m/s: 5 and 20 kg, ideal drives
    and the simulated ODrive's position loop, unshaped and shaped; then the loop's ticks
    uneven by up to 30 and 90 % (5 kg, ODrive loop)."""
    data = robot_data("paper")
    start, target = (0.0, 0.0, 2.0), (0.0, 0.0, 4.0)
    cases: list[tuple[float, bool, float]] = [
        (mass, odrive, 0.0) for odrive in (False, True) for mass in (5.0, 20.0)
    ]
    cases += [(5.0, True, 0.3), (5.0, True, 0.9)]
    for mass, odrive, jitter in cases:
        res = {}
        for shaped in (False, True):
            cfg = robot_config(
                data,
                mass_kg=mass,
                plant_ea_n=PAPER_EA_N,
                model_ea_n=PAPER_EA_N,
                start_m=start,
                shaper={"type": kind} if shaped else None,
                max_tension_n=ROBOTS["paper"]["max_tension_n"],
            )
            rig = PlantRig(cfg, odrive_loop=odrive, jitter=jitter)
            res[shaped] = rig.move(target, 1.0)
        drives = "ODrive loop" if odrive else "ideal drives"
        ticks = f", ticks +-{jitter * 100:.0f} %" if jitter else ""
        print(
            f"paper {mass:4g} kg, {drives}{ticks}: residual {res[False].residual_m * 1e3:.3f} mm "
            f"unshaped, {res[True].residual_m * 1e3:.4f} mm shaped",
            flush=True,
        )


def _vec(text: str) -> Vec3:
    """X,Y,Z in metres; argparse's error for anything else."""
    try:
        x, y, z = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a pose is X,Y,Z in metres, not {text!r}") from None
    return (x, y, z)


def _p(p: Sequence[float]) -> str:
    return "(" + ", ".join(f"{v:g}" for v in p) + ")"


def square_points() -> list[Vec3]:
    """`config/square-path.csv`'s points."""
    out = []
    for line in (ROOT / "config" / "square-path.csv").read_text().splitlines():
        if not line or line.startswith("#") or line.startswith("x"):
            continue
        x, y, z = (float(v) for v in line.split(","))
        out.append((x, y, z))
    return out


def vase_points(layers_z_mm: float, origin: Vec3) -> tuple[list[Vec3], Vec3]:
    """The vase job's points from its first layer up to `layers_z_mm` of height (robot
    frame, G-code origin at `origin`), and its start point."""
    from controller.core.gcode import parse_lines
    from controller.core.gcode_job import GcodeFrame, Interpreter, Motion

    frame = GcodeFrame(origin_m=origin, unit_m=0.001, max_speed_mps=1.0, max_accel_mps2=1.0)
    it = Interpreter(frame, origin)
    pts: list[Vec3] = []
    with gzip.open(ROOT / "tests" / "data" / "vase.gcode.gz", "rt") as f:
        for line in parse_lines(text.rstrip("\n") for text in f):
            for act in it.feed(line):
                if isinstance(act, Motion):
                    # from the first layer (after the start's lift) to the first point above
                    if max(p[2] for p in act.points_m) > origin[2] + layers_z_mm * 1e-3:
                        if pts:
                            return pts, origin
                        continue
                    pts.extend(act.points_m)
    return pts, origin


def path_deviation(rig: PlantRig, points: Sequence[Vec3], speed_mps: float) -> tuple[float, float]:
    """Fly `points` as one path; the largest distance (m) of the set-point and of the truth
    from the programmed polyline (start, then the points), from the start to 3 s after the
    end."""
    import numpy as np
    from scipy.spatial import cKDTree

    from controller.core.commands import Path as PathCmd
    from controller.core.states import State

    start = rig.ctl.setpoint_m
    assert start is not None
    poly = np.array([start, *points], dtype=float)
    dense = [poly[:1]]
    for a, b in itertools.pairwise(poly):
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / 5e-5))
        dense.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    tree = cKDTree(np.vstack(dense))
    fut = rig.ctl.submit(PathCmd(tuple(points), speed_mps))
    rig.tick(1)
    if fut.done() and fut.exception(timeout=0) is not None:
        raise RuntimeError(f"path refused: {fut.exception(timeout=0)}")
    sps: list[Vec3] = []
    truths: list[Vec3] = []
    ending = 0
    while ending < round(3.0 / rig.period_s):
        rig.tick(1)
        sp = rig.ctl.setpoint_m
        assert sp is not None
        sps.append(sp)
        truths.append(rig.plant.position_m)
        if rig.ctl.state is not State.MOVING:
            ending += 1
    d_sp, _ = tree.query(np.array(sps))
    d_truth, _ = tree.query(np.array(truths))
    return float(d_sp.max()), float(d_truth.max())


def paths(kind: str) -> None:
    """The path figures (module docstring)."""
    square = square_points()
    for shaped in (False, True):
        cfg = robot_config(
            robot_data("paper"),
            mass_kg=5.0,
            plant_ea_n=PAPER_EA_N,
            model_ea_n=PAPER_EA_N,
            start_m=(0.0, 0.0, 2.0),
            shaper={"type": kind} if shaped else None,
        )
        sp, truth = path_deviation(PlantRig(cfg), square, 1.0)
        print(
            f"square, paper robot 5 kg, 1 m/s, shaper {'on: ' + kind if shaped else 'off'}: "
            f"set-point {sp * 1e3:.2f} mm, truth {truth * 1e3:.2f} mm from the path "
            f"(junction deviation {cfg.limits.junction_deviation_m * 1e3:g} mm)",
            flush=True,
        )
    origin = (0.0, 0.0, 0.1)
    pts, _ = vase_points(0.4, origin)  # the first two layers: 820 points, one path command
    for shaped in (False, True):
        cfg = robot_config(
            robot_data("desk"),
            mass_kg=0.5,
            plant_ea_n=DESK_EA_N,
            model_ea_n=DESK_EA_N,
            start_m=origin,
            shaper={"type": kind} if shaped else None,
        )
        sp, truth = path_deviation(PlantRig(cfg), pts, 0.04)
        print(
            f"vase, first 2 layers ({len(pts)} points), desk rig 0.5 kg, 40 mm/s, shaper "
            f"{'on: ' + kind if shaped else 'off'}: set-point {sp * 1e3:.3f} mm, truth "
            f"{truth * 1e3:.3f} mm from the path (junction deviation "
            f"{cfg.limits.junction_deviation_m * 1e3:g} mm)",
            flush=True,
        )


def main(argv: Sequence[str] | None = None) -> int:
    """The command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("what", choices=("moves", "paths", "vertical", "offset"))
    ap.add_argument("robot", nargs="?", default="paper", choices=tuple(ROBOTS))
    ap.add_argument("--type", default=DEFAULT_SHAPER_TYPE, help="the shaper's type")
    ap.add_argument("--quick", action="store_true", help="three poses only")
    ap.add_argument("--mass", type=float, action="append", help="payloads (kg; repeatable)")
    ap.add_argument(
        "--pose", action="append", type=_vec, help="start poses --pose=X,Y,Z (m; repeatable)"
    )
    ap.add_argument(
        "--direction", action="append", choices=tuple(DIRECTION_NAMES), help="directions"
    )
    ap.add_argument(
        "--model-error", type=float, action="append", help="the model's EA / the plant's"
    )
    ap.add_argument(
        "--frequency-scale", type=float, default=1.0, help="the shaped runs' frequency_scale"
    )
    ap.add_argument("--speed", type=float, default=None, help="the moves' speed (m/s)")
    ap.add_argument("--passes", type=int, default=1, help="the shaped runs' [shaper] passes")
    args = ap.parse_args(argv)
    sel = Selection(
        poses=list(args.pose) if args.pose else None,
        directions=[DIRECTIONS[DIRECTION_NAMES[d]] for d in args.direction]
        if args.direction
        else None,
        errors=tuple(args.model_error) if args.model_error else MODEL_ERRORS,
        masses=tuple(args.mass) if args.mass else None,
        frequency_scale=args.frequency_scale,
        speed_mps=args.speed,
        passes=args.passes,
    )
    if args.what == "moves":
        moves(args.robot, args.type, args.quick, sel)
    elif args.what == "offset":
        offset(args.robot, sel)
    elif args.what == "vertical":
        vertical(args.type)
    else:
        paths(args.type)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
