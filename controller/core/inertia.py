"""The payload's inertia in the planned tensions: what the cables must add to accelerate it.

Pure (``math``), no I/O. Statics (`controller.core.statics`) gives the tensions that hold the
payload still, ``sum t_i u_i = m g e_z``. Accelerating at ``a`` the cables must supply
``m (g e_z + a)``: the held tensions plus a share ``dt`` with ``sum dt_i u_i = m a``. This is
the least-norm such share, ``dt_i = u_i . y`` with ``(sum u_i u_i^T) y = m a``: it spreads the
force over every cable in proportion to how well it points along it, and adds nothing to the
held distribution's internal tension (the null space is the statics' choice). With the
stretch model (`controller.core.stretch`) the cables are then paid out for the tensions they
really pull while the payload accelerates, so the effector follows the set-point instead of
lagging it by ``m a / k`` and ringing when the acceleration stops.

The tension rule is the statics' (the held distribution, `tension_margin_n` inside the limits,
which is the room the share takes: mass times acceleration); a share that would make a cable
push leaves it at zero (it goes slack, the stretch model pays it out as unloaded).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Vec3 = tuple[float, float, float]


def inertial_share(
    anchors_m: Sequence[Vec3], position_m: Vec3, mass_kg: float, accel_mps2: Vec3
) -> tuple[float, ...] | None:
    """The least-norm tension share (N per cable, may be negative) with which the cables
    accelerate `mass_kg` at `accel_mps2` from `position_m` (module docstring); None where the
    cables do not span every direction (fewer than three independent ones) or the effector is
    on an anchor. All zero for no acceleration. Raises nothing for finite inputs."""
    ax, ay, az = accel_mps2
    n = len(anchors_m)
    if ax == 0.0 and ay == 0.0 and az == 0.0:
        return (0.0,) * n
    x, y, z = position_m
    units = []
    m11 = m12 = m13 = m22 = m23 = m33 = 0.0
    for a in anchors_m:
        dx = a[0] - x
        dy = a[1] - y
        dz = a[2] - z
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        if not length > 0.0:
            return None
        ux, uy, uz = dx / length, dy / length, dz / length
        units.append((ux, uy, uz))
        m11 += ux * ux
        m12 += ux * uy
        m13 += ux * uz
        m22 += uy * uy
        m23 += uy * uz
        m33 += uz * uz
    c11 = m22 * m33 - m23 * m23
    c12 = m13 * m23 - m12 * m33
    c13 = m12 * m23 - m13 * m22
    det = m11 * c11 + m12 * c12 + m13 * c13
    if not abs(det) > 1e-12:
        return None
    c22 = m11 * m33 - m13 * m13
    c23 = m12 * m13 - m11 * m23
    c33 = m11 * m22 - m12 * m12
    fx, fy, fz = mass_kg * ax, mass_kg * ay, mass_kg * az
    yx = (c11 * fx + c12 * fy + c13 * fz) / det
    yy = (c12 * fx + c22 * fy + c23 * fz) / det
    yz = (c13 * fx + c23 * fy + c33 * fz) / det
    return tuple([ux * yx + uy * yy + uz * yz for ux, uy, uz in units])


def with_inertia(held_n: Sequence[float], share_n: Sequence[float] | None) -> tuple[float, ...]:
    """The held tensions plus the inertial share, none below zero (a cable cannot push: it
    goes slack). `held_n` alone when there is no share. Raises nothing."""
    if share_n is None:
        return tuple(held_n)
    return tuple([v if (v := t + s) > 0.0 else 0.0 for t, s in zip(held_n, share_n, strict=True)])
