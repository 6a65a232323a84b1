"""The effector's vibration modes at a pose: natural frequencies, damping ratios and directions.

Pure module (``math``, ``numpy``), no I/O, no threads.

A cable robot's effector is a mass on springs. Linearised about a pose P where cable ``i``
(anchor ``A_i``, length ``L_i = |A_i - P|``, unit vector ``u_i = (A_i - P) / L_i``) pulls the
tension ``t_i``, a small displacement ``x`` of the effector meets the restoring force ``-K x``
with the stiffness

    K = K_a + K_g,    K_a = sum k_i u_i u_i^T,    K_g = sum (t_i / L_i) (I - u_i u_i^T)

``K_a`` is the cables' axial stiffness, ``k_i = EA_i / L0_i`` with the unstretched length
``L0_i = L_i EA_i / (EA_i + t_i)``; ``K_g`` is the tensions' geometric stiffness (a taut string
pulled sideways: a pendulum's restoring force). The effector's modes are the eigenvectors of
``K / m`` (``m`` the payload's mass), their natural frequencies the square roots of its
eigenvalues over 2 pi. On the paper robot with 5 kg on EA 4.5e5 N cables the vertical mode at
(0, 0, 2) m is 1.6 Hz, the horizontal ones 7 and 12 Hz; on a desk rig they are tens of Hz.

Damping: the ropes' hysteresis damps each mode of ``K_a`` at the ropes' damping ratio
``zeta`` (the damping matrix ``2 zeta sqrt(m K_a)``, as `controller.core.plant` simulates
it), a drag ``c`` adds ``c / (2 m omega)``. A mode's damping ratio is its share of that
damping, ``phi^T C phi / (2 m omega)`` for its unit direction ``phi`` (exact when the geometric
stiffness is small beside the axial, as on every practical rig; the modes stay real).

Nothing here returns NaN: a cable without an EA (a rigid model), a slack cable (no tension), a
non-finite input or an effector on an anchor raise `ModesError` with the reason.

`ModeTracker` gives the natural frequencies alone, in scalar Python (a closed-form 3x3
eigenvalue solution, a few microseconds), for the control loop's input shaper at every tick.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

Vec3 = tuple[float, float, float]

__all__ = [
    "ModeTracker",
    "Modes",
    "ModesError",
    "effector_modes",
    "rope_damping",
    "stiffness_matrices",
]

SOFT_MODE = 1e-12
"""An axial stiffness eigenvalue below this fraction of the largest has no mode to damp (a
direction no taut cable stiffens)."""


class ModesError(ValueError):
    """The modes cannot be computed: a rigid model (no EA), a slack cable, a bad input."""


@dataclass(frozen=True, slots=True)
class Modes:
    """The effector's three modes at one pose, ascending in frequency.

    ``frequencies_hz``: undamped natural frequencies; ``damping_ratios``: each mode's damping
    ratio; ``directions``: each mode's direction of motion (unit vectors, the largest component
    positive); ``tensions_n``: the cable tensions the stiffness was computed with.
    """

    frequencies_hz: tuple[float, float, float]
    damping_ratios: tuple[float, float, float]
    directions: tuple[Vec3, Vec3, Vec3]
    tensions_n: tuple[float, ...]


def _checked(
    anchors_m: Sequence[Sequence[float]],
    position_m: Sequence[float],
    tensions_n: Sequence[float],
    ea_n: Sequence[float | None],
    mass_kg: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Inputs as arrays (anchors, pose, tensions, EA) and the mass; ModesError if unusable."""
    try:
        a = np.asarray(anchors_m, dtype=np.float64).reshape(-1, 3)
        p = np.asarray(position_m, dtype=np.float64).reshape(3)
        t = np.asarray(tensions_n, dtype=np.float64).reshape(-1)
        m = float(mass_kg)
    except (TypeError, ValueError):
        raise ModesError("anchors, pose, tensions and mass must be numbers") from None
    n = a.shape[0]
    if n < 3 or t.shape[0] != n or len(ea_n) != n:
        raise ModesError(f"{n} anchors need as many tensions and EA values (and at least 3)")
    missing = [i + 1 for i, e in enumerate(ea_n) if e is None]
    if missing:
        which = _cables(missing)
        raise ModesError(
            f"{which} {'has' if len(missing) == 1 else 'have'} no EA (`[[reels]] cable_ea_n`): "
            "a rigid model has no modes"
        )
    ea = np.asarray([float(e) for e in ea_n if e is not None], dtype=np.float64)
    if not (np.isfinite(a).all() and np.isfinite(p).all() and np.isfinite(t).all()):
        raise ModesError("anchors, pose and tensions must be finite")
    if not (np.isfinite(ea).all() and (ea > 0.0).all()):
        raise ModesError("every cable's EA must be finite and > 0 N")
    if not (math.isfinite(m) and m > 0.0):
        raise ModesError(f"the payload's mass must be finite and > 0 kg, got {mass_kg!r}")
    slack = [i + 1 for i in range(n) if not t[i] > 0.0]
    if slack:
        verb = "is" if len(slack) == 1 else "are"
        raise ModesError(
            f"{_cables(slack)} {verb} slack at {_fmt(p.tolist())} (no tension): the effector's "
            "modes there are not the cables'"
        )
    return a, p, t, ea, m


def stiffness_matrices(
    anchors_m: Sequence[Sequence[float]],
    position_m: Sequence[float],
    tensions_n: Sequence[float],
    ea_n: Sequence[float | None],
) -> tuple[np.ndarray, np.ndarray]:
    """The axial and the geometric stiffness (3x3, N/m) of the cables at `position_m` pulling
    `tensions_n` (module docstring). Raises ModesError as `effector_modes` does."""
    a, p, t, ea, _ = _checked(anchors_m, position_m, tensions_n, ea_n, 1.0)
    d = a - p
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    if not (length > 0.0).all():
        raise ModesError(f"the effector is on an anchor at {_fmt(p.tolist())}")
    u = d / length[:, None]
    k = (ea + t) / length  # EA / L0 with L0 = L EA / (EA + t)
    g = t / length
    k_axial = (u.T * k) @ u
    k_geo = np.eye(3) * float(g.sum()) - (u.T * g) @ u
    return k_axial, k_geo


def rope_damping(
    k_axial: np.ndarray, mass_kg: float, damping_ratio: float
) -> tuple[np.ndarray, np.ndarray]:
    """The ropes' damping at the axial stiffness `k_axial` (3x3, N/m) of an effector of
    `mass_kg`: (C, G), the damping matrix C = 2 zeta sqrt(m K_a) (N s/m), which damps each
    mode of K_a at `damping_ratio`, and the gain G = 2 zeta sqrt(m) K_a^(-1/2) (s) that turns
    the cables' stiffness-weighted strain rates ``sum k_i de_i/dt u_i`` into that force (the
    plant's, `controller.core.plant`). Directions K_a does not stiffen (fewer than three taut
    cables) get neither. Raises nothing for a symmetric finite matrix."""
    lam, vec = np.linalg.eigh(k_axial)
    top = float(lam[-1])
    if not top > 0.0:
        zero = np.zeros((3, 3))
        return zero, zero
    stiff = lam > SOFT_MODE * top
    root = np.sqrt(np.where(stiff, lam, 1.0))
    scale = 2.0 * float(damping_ratio) * math.sqrt(float(mass_kg))
    c = (vec * np.where(stiff, scale * root, 0.0)) @ vec.T
    g = (vec * np.where(stiff, scale / root, 0.0)) @ vec.T
    return c, g


def effector_modes(
    anchors_m: Sequence[Sequence[float]],
    position_m: Sequence[float],
    tensions_n: Sequence[float],
    ea_n: Sequence[float | None],
    mass_kg: float,
    *,
    cable_damping_ratio: float = 0.0,
    effector_damping_n_s_per_m: float = 0.0,
) -> Modes:
    """The effector's modes at `position_m` with the cables pulling `tensions_n` (the statics
    solution there) and the payload `mass_kg` (module docstring).

    `ea_n` is each cable's EA (None: rigid); the damping ratios come from the ropes'
    `cable_damping_ratio` and the effector's drag `effector_damping_n_s_per_m`. Raises
    ModesError for a rigid cable, a slack one (tension <= 0), an effector on an anchor, a
    non-finite input, a negative damping or a stiffness with no mode in some direction.
    """
    zeta = float(cable_damping_ratio)
    drag = float(effector_damping_n_s_per_m)
    if not (math.isfinite(zeta) and zeta >= 0.0 and math.isfinite(drag) and drag >= 0.0):
        raise ModesError("damping ratio and drag must be finite and >= 0")
    _, _, t, _, m = _checked(anchors_m, position_m, tensions_n, ea_n, mass_kg)
    k_axial, k_geo = stiffness_matrices(anchors_m, position_m, tensions_n, ea_n)
    lam, vec = np.linalg.eigh((k_axial + k_geo) / m)
    if not (np.isfinite(lam).all() and lam[0] > 0.0):
        raise ModesError(f"the cables do not hold the effector in every direction at {position_m}")
    # the ropes' damping matrix 2 zeta sqrt(m K_a), plus the drag
    damping = rope_damping(k_axial, m, zeta)[0] + drag * np.eye(3)
    omega = np.sqrt(lam)
    freqs = []
    ratios = []
    dirs = []
    for j in range(3):
        phi = vec[:, j]
        if phi[int(np.argmax(np.abs(phi)))] < 0.0:
            phi = -phi
        freqs.append(float(omega[j] / (2.0 * math.pi)))
        ratios.append(float(phi @ damping @ phi) / (2.0 * m * float(omega[j])))
        dirs.append((float(phi[0]), float(phi[1]), float(phi[2])))
    return Modes(
        (freqs[0], freqs[1], freqs[2]),
        (ratios[0], ratios[1], ratios[2]),
        (dirs[0], dirs[1], dirs[2]),
        tuple(float(v) for v in t),
    )


def _sym3_eigenvalues(
    a11: float, a12: float, a13: float, a22: float, a23: float, a33: float
) -> tuple[float, float, float]:
    """Eigenvalues of a symmetric 3x3 matrix, ascending (the trigonometric closed form)."""
    p1 = a12 * a12 + a13 * a13 + a23 * a23
    q = (a11 + a22 + a33) / 3.0
    if p1 == 0.0:
        lo, mid, hi = sorted((a11, a22, a33))
        return lo, mid, hi
    b11 = a11 - q
    b22 = a22 - q
    b33 = a33 - q
    p2 = b11 * b11 + b22 * b22 + b33 * b33 + 2.0 * p1
    p = math.sqrt(p2 / 6.0)
    # r = det(B / p) / 2
    det = (
        b11 * (b22 * b33 - a23 * a23)
        - a12 * (a12 * b33 - a23 * a13)
        + a13 * (a12 * a23 - b22 * a13)
    )
    r = det / (2.0 * p * p * p)
    phi = math.pi / 3.0 if r <= -1.0 else 0.0 if r >= 1.0 else math.acos(r) / 3.0
    hi = q + 2.0 * p * math.cos(phi)
    lo = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)
    return lo, 3.0 * q - hi - lo, hi


class ModeTracker:
    """The model's natural frequencies as the effector moves: per tick, in scalar Python.

    Built once from the anchors, each cable's EA (all known), the payload's mass and a
    correction `scale` the frequencies are multiplied by (a measured over a modelled
    frequency, `cablebot resonance`). `frequencies_hz` gives the three natural frequencies
    (ascending) at a pose with the cables' tensions there, or None when they cannot be had
    (a slack cable, a degenerate pose). Raises ModesError on construction for a rigid cable, a
    non-finite or non-positive EA, mass or scale.
    """

    __slots__ = ("_anchors", "_ea", "_inv_m", "_scale")

    def __init__(
        self,
        anchors_m: Sequence[Sequence[float]],
        ea_n: Sequence[float | None],
        mass_kg: float,
        scale: float = 1.0,
    ) -> None:
        anchors = tuple((float(a[0]), float(a[1]), float(a[2])) for a in anchors_m)
        if len(ea_n) != len(anchors) or None in ea_n:
            raise ModesError("every cable needs its EA (`[[reels]] cable_ea_n`) for the model")
        ea = tuple(float(e) for e in ea_n if e is not None)
        if not all(math.isfinite(e) and e > 0.0 for e in ea):
            raise ModesError("every cable's EA must be finite and > 0 N")
        m = float(mass_kg)
        s = float(scale)
        if not (math.isfinite(m) and m > 0.0 and math.isfinite(s) and s > 0.0):
            raise ModesError("mass and frequency scale must be finite and > 0")
        self._anchors = anchors
        self._ea = ea
        self._inv_m = 1.0 / m
        self._scale = s

    def frequencies_hz(
        self, position_m: Sequence[float], tensions_n: Sequence[float]
    ) -> tuple[float, float, float] | None:
        """The scaled natural frequencies (Hz, ascending) at `position_m` with `tensions_n`,
        or None where a cable is slack, the effector is on an anchor or a direction has no
        stiffness. Raises nothing."""
        x, y, z = position_m
        kxx = kyy = kzz = kxy = kxz = kyz = geo = 0.0
        for (ax, ay, az), ea, t in zip(self._anchors, self._ea, tensions_n, strict=False):
            if not t > 0.0:
                return None
            dx = ax - x
            dy = ay - y
            dz = az - z
            d2 = dx * dx + dy * dy + dz * dz
            if not d2 > 0.0:
                return None
            length = math.sqrt(d2)
            g = t / length
            s = ((ea + t) / length - g) / d2
            kxx += s * dx * dx
            kyy += s * dy * dy
            kzz += s * dz * dz
            kxy += s * dx * dy
            kxz += s * dx * dz
            kyz += s * dy * dz
            geo += g
        f = self._inv_m
        lo, mid, hi = _sym3_eigenvalues(
            (kxx + geo) * f, kxy * f, kxz * f, (kyy + geo) * f, kyz * f, (kzz + geo) * f
        )
        if not (lo > 0.0 and hi < math.inf):
            return None
        c = self._scale / (2.0 * math.pi)
        return (math.sqrt(lo) * c, math.sqrt(mid) * c, math.sqrt(hi) * c)


def _cables(numbers: Sequence[int]) -> str:
    """ "cable 2" or "cables 1, 3" (1-based numbers)."""
    if len(numbers) == 1:
        return f"cable {numbers[0]}"
    return "cables " + ", ".join(str(i) for i in numbers)


def _fmt(p: Sequence[float]) -> str:
    return "(" + ", ".join(f"{float(v):.4g}" for v in p) + ") m"
