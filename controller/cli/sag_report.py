"""What `cablebot check-config` says about heavy cables (`[[reels]] cable_mass_kg_per_m`): how
much they sag at a few poses and how far the effector would hang from its target if the
controller did not model it.

At each pose the statics with the cables' weight (``controller.core.sag``) give every cable's
catenary: its mid-span drop below the chord and the cable the reel pays out beyond what the
straight model (stretch included) would pay out.  The pose error unmodelled is the physical
plant's rest pose (``controller.core.sag_plant.sag_equilibrium``) when the reels pay out the
straight model's lengths, homed at the power-up pose as the controller homes (so the error is
zero there; without a power-up pose, the lengths as commanded): what a controller configured
without `cable_mass_kg_per_m` would do to this robot.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

Vec3 = tuple[float, float, float]


def sag_poses(
    cfg: Any,
    centre_xy: tuple[float, float],
    corner_xy: tuple[float, float],
    floor_z: float,
    top_z: float,
) -> list[tuple[str, Vec3]]:
    """The poses the report looks at: the power-up pose, the workspace's centre line at the
    floor, half-way and the top, and a corner of the workspace box at the floor (the longest
    cables). Raises nothing."""
    poses: list[tuple[str, Vec3]] = []
    pu = cfg.homing.power_up_position_m
    if pu is not None:
        poses.append(("power-up", (float(pu[0]), float(pu[1]), float(pu[2]))))
    cx, cy = centre_xy
    for name, z in (("floor", floor_z), ("middle", (floor_z + top_z) / 2.0), ("top", top_z)):
        poses.append((name, (cx, cy, z)))
    poses.append(("corner", (corner_xy[0], corner_xy[1], floor_z)))
    return poses


def sag_lines(
    cfg: Any, poses: Sequence[tuple[str, Vec3]]
) -> tuple[list[str], list[dict[str, Any]]] | None:
    """The check-config lines on cable sag (None: massless cables or no payload) and their
    JSON: per pose the largest mid-span drop and extra paid-out length of any cable, and the
    unmodelled pose error (module docstring). Raises nothing."""
    masses = [float(r.cable_mass_kg_per_m or 0.0) for r in cfg.reels]
    if not any(masses) or cfg.payload is None or cfg.tension is None:
        return None
    from controller.core import catenary, kinematics
    from controller.core.plant import EquilibriumError, PlantError, PlantParams
    from controller.core.sag_plant import sag_equilibrium
    from controller.core.statics import StaticsError
    from controller.core.stretch import CableStretch, StretchError
    from controller.service.config import tension_check

    check = tension_check(cfg.payload, cfg.tension, cfg.geometry, cfg.reels)
    sag = check.sag  # type: ignore[attr-defined]
    eas = [r.cable_ea_n for r in cfg.reels]
    straight = CableStretch(
        cfg.geometry, eas, tension_check(cfg.payload, cfg.tension, cfg.geometry)
    )
    # the plant needs an EA: inextensible cables get one far stiffer than any rope
    plant = PlantParams(
        cfg.anchors_m,
        [e if e is not None else 1e12 for e in eas],
        float(cfg.payload.mass_kg),
        cable_mass_kg_per_m=masses,
    )

    def straight_paid(p: Vec3) -> tuple[float, ...]:
        if straight.rigid:
            return tuple(kinematics.ipk_point(cfg.geometry, p))
        return straight.ipk(p)[0]

    offset: list[float] | None = [0.0] * len(masses)
    pu = cfg.homing.power_up_position_m
    if pu is not None:
        try:
            at = (float(pu[0]), float(pu[1]), float(pu[2]))
            true_pu = sag.solve(at).paid_out_m
            offset = [t - s for t, s in zip(true_pu, straight_paid(at), strict=True)]
        except (StaticsError, StretchError, kinematics.KinematicsError):
            offset = None
    rows: list[str] = []
    out: list[dict[str, Any]] = []
    w = sag.weight_n_per_m
    for name, p in poses:
        where = f"{name} ({', '.join(f'{v:.4g}' for v in p)})"
        try:
            sol = sag.solve(p)
            base = straight_paid(p)
        except (StaticsError, StretchError, kinematics.KinematicsError) as exc:
            rows.append(f"  {where:28s} {exc}")
            continue
        drops = []
        for i, (ax, ay, az) in enumerate(cfg.anchors_m):
            span = ((ax - p[0]) ** 2 + (ay - p[1]) ** 2) ** 0.5
            try:
                ends = catenary.from_horizontal_force(
                    span, az - p[2], sol.horizontal_n[i], w[i], _compliance(eas[i])
                )
                drops.append(catenary.sag(ends, span, az - p[2], w[i], _compliance(eas[i]))[0])
            except catenary.CatenaryError:  # a vertical cable hangs along its chord
                drops.append(0.0)
        extra = [a - b for a, b in zip(sol.paid_out_m, base, strict=True)]
        error_m: float | None = None
        if offset is not None:
            lengths = [b + o for b, o in zip(base, offset, strict=True)]
            try:
                rest = sag_equilibrium(plant, lengths, guess_m=p).position_m
                error_m = sum((a - b) ** 2 for a, b in zip(rest, p, strict=True)) ** 0.5
            except (PlantError, EquilibriumError):
                error_m = None
        k = max(range(len(drops)), key=lambda j: drops[j])
        e = max(range(len(extra)), key=lambda j: abs(extra[j]))
        unmodelled = ""
        if error_m is not None:
            small = 0.0 < error_m < 1e-4
            off = f"{error_m * 1e6:.2f} um" if small else f"{error_m * 1e3:.1f} mm"
            unmodelled = f"; unmodelled {off} off"
        if sol.margin_n < check.margin_n:
            unmodelled += " (beyond the tension limits there)"
        more = f"{extra[e] * 1e3:+.1f} mm" if abs(extra[e]) >= 1e-4 else f"{extra[e] * 1e6:+.1f} um"
        rows.append(
            f"  {where:28s} drop {drops[k]:.3g} m (cable {k + 1}), "
            f"{more} of cable (cable {e + 1}){unmodelled}"
        )
        out.append(
            {
                "pose": name,
                "position_m": list(p),
                "mid_span_drop_m": drops,
                "extra_paid_out_m": extra,
                "unmodelled_error_m": error_m,
            }
        )
    known = sorted(set(masses))
    head = (
        f"sag        cables of {'/'.join(f'{m:g}' for m in known)} kg/m hang in catenaries "
        "(modelled); the most any cable drops below its chord at mid-span, the cable paid out "
        "beyond a straight cable's, and how far the effector would hang from the pose without "
        + (
            "the model (homed at the power-up pose):"
            if pu is not None
            else "the model (no power-up pose: the lengths as commanded):"
        )
    )
    return [head, *rows], out


def _compliance(ea: float | None) -> float:
    return 0.0 if ea is None else 1.0 / ea
