"""Physical plant of a cable-suspended robot: a damped point mass hanging from elastic cables.

Pure module (``math`` and ``numpy``, no I/O, no threads, no global state). It stands in for the
real robot behind simulated reels: the reels decide how much cable is out, the plant says where
the effector goes and what each cable pulls.

Model
-----
* World frame z up, SI units. Cable ``i`` runs from its anchor ``A_i`` (pulley exit point) to the
  effector ``P``, a point mass ``m``. Its unstretched length ``L0_i`` is what the reel has paid out:
  the caller turns motor positions into metres (``controller.core.reel.ReelModel.length_m`` gives
  the unstretched length) and passes metres in; the reel model stays out of the plant.
  `ReelPlant` is that caller for a bank of reels: motor turns in, holding torques out; a reel
  in torque control instead pulls its cable with a set tension and the plant turns it.
* Cable stiffness ``k_i = EA_i / L0_i`` (``EA`` in newtons: about 1e5 N for a desk rig's braided
  line, 1e6-1e7 N for steel rope). With ``L_i = |A_i - P|`` and ``u_i = (A_i - P) / L_i``, the
  elastic tension is

      t_i = k_i * e_i   if e_i = L_i - L0_i > 0,   else 0

  A cable paid out beyond the distance is slack and carries nothing.
* The effector: ``m a = sum(t_i u_i) + f_d - m g e_z - c v``, with ``f_d`` the ropes' own
  damping (below) and ``c`` a drag on the effector.

Damping
-------
* The ropes (``cable_damping_ratio``, zeta). Rope loses a roughly constant fraction of its
  strain energy per cycle whatever the frequency (hysteretic damping), so every mode its
  stretch stiffens rings down at the same ratio, the slow vertical bounce as much as the fast
  horizontal modes. With the taut cables' axial stiffness ``K_a = sum k_i u_i u_i^T`` (at the
  start of each step) the damping force is ``f_d = G sum_i k_i de_i/dt u_i`` with
  ``G = 2 zeta sqrt(m) K_a^(-1/2)`` (`controller.core.vibration.rope_damping`): a
  Kelvin-Voigt rope, on the strain rate ``de_i/dt = -u_i . v - dL0_i/dt``, whose retardation
  time is ``2 zeta / omega_j`` in each axial mode j. On fixed lengths that is the damping
  matrix ``2 zeta sqrt(m K_a)``, which damps each axial mode at exactly zeta (a mode the
  tensions' geometric stiffness also stiffens keeps zeta times the stretch's share of its
  stiffness: `controller.core.vibration.effector_modes`). Acting on the strain rate, it does
  not drag an effector that follows its cables; a rope slackening fast is never pushed by its
  damping. 0.02 (`DEFAULT_CABLE_DAMPING_RATIO`) is a realistic rope, 1.0 critical.
* ``c`` (``effector_damping_n_s_per_m``, default ``DEFAULT_EFFECTOR_DAMPING_PER_S * m``): a
  light drag for what the cables do not stiffen (a swing on two taut cables, reels in torque
  control), half a per cent of critical at the paper robot's 1.6 Hz vertical mode.
* The damping forces act on the effector; the tensions reported are the elastic ones.

Integration
-----------
``step`` uses velocity Verlet (kick, drift, kick: symplectic, second order, one force evaluation
per sub-step) in sub-steps; the last force evaluation is at the final pose with the final
unstretched lengths, so the tensions it reports belong to them. The unstretched lengths move
linearly from the previous step's to the new ones across the sub-steps (the reels turn
continuously), which also gives the strain rate its ``dL0/dt``. Undamped, the scheme is stable
while ``h omega < 2``; for one mode ``x'' = -omega^2 x - gamma x'`` the sub-step ``h`` is chosen
so that ``(h omega)^2 + 2 h gamma <= 1`` (the undamped limit is 4; measured with the damping
taken at the half-step velocity, the scheme goes unstable between 4 and 6), with ``omega^2``
bounded from above at the start of every step by the Gershgorin (or trace) bound of the
stiffness ``sum k_i u_i u_i^T`` over *all* cables (slack ones too: one may tighten within the
step) with ``k_i`` at the shorter of the two unstretched lengths, plus the geometric stiffness
``sum t_i / L_i``. So the sub-step count follows the stiffness and the mass (1 kg on four 1e5 N
lines about 0.8 m long: two sub-steps per millisecond; 0.5 kg on 1e7 N steel: 24), bounded by
``max_substeps``. With four cables a sub-step costs about 2 us of scalar Python (numpy costs
more on arrays this small), a step about 5 us more for the bound and the checks, and the
damping gain's 3x3 eigendecomposition (25 us) when the pose or the lengths have moved
(`GAIN_REUSE`). The step is bounded by stability, not accuracy: a stiff rig stepped at 1 kHz
rings up to 3 % faster than its continuous model (the desk rig), under 0.2 % at 5 kHz.

Nothing here returns NaN or inf: inputs are checked (`PlantError`), a state that stops being
finite raises `PlantDivergedError`, an equilibrium that cannot be found `EquilibriumError`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from controller.core.plant_checks import PlantError as PlantError
from controller.core.plant_checks import finite as _finite
from controller.core.plant_checks import non_negative as _non_negative
from controller.core.plant_checks import positive as _positive
from controller.core.plant_checks import vec3 as _vec3
from controller.core.reel import ReelModel
from controller.core.vibration import rope_damping

STANDARD_GRAVITY_MPS2 = 9.80665
"""Standard gravity, m/s^2 (z is up)."""
DEFAULT_CABLE_DAMPING_RATIO = 0.02
"""Damping ratio of every mode the cables' stretch stiffens: a realistic rope (module
docstring)."""
DEFAULT_EFFECTOR_DAMPING_PER_S = 0.1
"""Default effector damping per kilogram of effector, (N s/m)/kg: a light drag."""
DEFAULT_MAX_SUBSTEPS = 1000
"""Most sub-steps one `CablePlant.step` may take (bounds its cost)."""

GAIN_REUSE = 1e-3
"""The ropes' damping gain is recomputed when the pose or an unstretched length moves by this
fraction of the shortest cable (its eigendecomposition costs more than a step's sub-steps)."""
_STABILITY = 1.0
"""Sub-steps keep (h omega)^2 + 2 h gamma at most this (the stability limit is 4)."""
_EPS = 2.0**-52

Vec3 = tuple[float, float, float]


class PlantDivergedError(PlantError):
    """The simulated state stopped being finite; the plant refuses to go on."""


class EquilibriumError(PlantError):
    """No static rest pose (or holding tension distribution) was found."""


class Equilibrium(NamedTuple):
    """A static rest pose: where the effector hangs and what each cable pulls."""

    position_m: Vec3
    tensions_n: tuple[float, ...]
    residual_n: float
    """Norm of the remaining force imbalance."""
    iterations: int


class PlantParams:
    """The fixed parameters of a plant: anchors, cable EA, effector mass, damping, gravity.

    `ea_n` is one EA (newtons) for every cable or one per cable. `effector_damping_n_s_per_m`
    defaults to `DEFAULT_EFFECTOR_DAMPING_PER_S * mass_kg`. `cable_mass_kg_per_m` (one for
    every cable or one per cable; default 0, massless) makes the cables hang in catenaries:
    such a plant is a `controller.core.sag_plant.SagPlant`. Raises PlantError on fewer than
    one anchor, non-finite coordinates, a non-positive or non-finite EA or mass, a negative or
    non-finite damping, gravity or cable mass, a wrong count of EA or cable mass values, or
    max_substeps < 1.
    """

    __slots__ = (
        "anchors_m",
        "cable_damping_ratio",
        "cable_weight_n_per_m",
        "ea_n",
        "effector_damping_n_s_per_m",
        "gravity_mps2",
        "mass_kg",
        "max_substeps",
    )

    anchors_m: tuple[Vec3, ...]
    ea_n: tuple[float, ...]
    mass_kg: float
    cable_damping_ratio: float
    effector_damping_n_s_per_m: float
    gravity_mps2: float
    max_substeps: int
    cable_weight_n_per_m: tuple[float, ...]
    """Each cable's weight per metre of unstretched cable, its mass per metre times gravity."""

    def __init__(
        self,
        anchors_m: Sequence[Sequence[float]],
        ea_n: float | Sequence[float],
        mass_kg: float,
        *,
        cable_damping_ratio: float = DEFAULT_CABLE_DAMPING_RATIO,
        effector_damping_n_s_per_m: float | None = None,
        gravity_mps2: float = STANDARD_GRAVITY_MPS2,
        max_substeps: int = DEFAULT_MAX_SUBSTEPS,
        cable_mass_kg_per_m: float | Sequence[float] = 0.0,
    ) -> None:
        anchors = tuple(_vec3(f"anchor {i + 1}", a) for i, a in enumerate(anchors_m))
        if not anchors:
            raise PlantError("a plant needs at least one cable")
        if isinstance(ea_n, int | float | np.number):
            ea = (_positive("ea_n", ea_n),) * len(anchors)
        else:
            if len(ea_n) != len(anchors):
                raise PlantError(f"ea_n has {len(ea_n)} values for {len(anchors)} cables")
            ea = tuple(_positive(f"ea_n of cable {i + 1}", v) for i, v in enumerate(ea_n))
        mass = _positive("mass_kg", mass_kg)
        if effector_damping_n_s_per_m is None:
            effector_damping_n_s_per_m = DEFAULT_EFFECTOR_DAMPING_PER_S * mass
        if isinstance(max_substeps, bool) or not isinstance(max_substeps, int) or max_substeps < 1:
            raise PlantError(f"max_substeps must be an int >= 1, got {max_substeps!r}")
        self.anchors_m = anchors
        self.ea_n = ea
        self.mass_kg = mass
        self.cable_damping_ratio = _non_negative("cable_damping_ratio", cable_damping_ratio)
        self.effector_damping_n_s_per_m = _non_negative(
            "effector_damping_n_s_per_m", effector_damping_n_s_per_m
        )
        self.gravity_mps2 = _non_negative("gravity_mps2", gravity_mps2)
        self.max_substeps = max_substeps
        if isinstance(cable_mass_kg_per_m, int | float | np.number):
            masses = (_non_negative("cable_mass_kg_per_m", cable_mass_kg_per_m),) * len(anchors)
        else:
            if len(cable_mass_kg_per_m) != len(anchors):
                raise PlantError(
                    f"cable_mass_kg_per_m has {len(cable_mass_kg_per_m)} values for "
                    f"{len(anchors)} cables"
                )
            masses = tuple(
                _non_negative(f"cable_mass_kg_per_m of cable {i + 1}", v)
                for i, v in enumerate(cable_mass_kg_per_m)
            )
        self.cable_weight_n_per_m = tuple(m * self.gravity_mps2 for m in masses)

    @property
    def cables(self) -> int:
        """Number of cables."""
        return len(self.anchors_m)

    @property
    def weight_n(self) -> float:
        """The effector's weight, m g (newtons)."""
        return self.mass_kg * self.gravity_mps2

    @property
    def sags(self) -> bool:
        """True when a cable has weight: the cables hang in catenaries (`SagPlant`)."""
        return any(w > 0.0 for w in self.cable_weight_n_per_m)

    def __repr__(self) -> str:
        return (
            f"PlantParams(anchors_m={self.anchors_m!r}, ea_n={self.ea_n!r}, "
            f"mass_kg={self.mass_kg!r}, cable_damping_ratio={self.cable_damping_ratio!r}, "
            f"effector_damping_n_s_per_m={self.effector_damping_n_s_per_m!r}, "
            f"gravity_mps2={self.gravity_mps2!r}, max_substeps={self.max_substeps!r}, "
            f"cable_weight_n_per_m={self.cable_weight_n_per_m!r})"
        )


def _lengths(params: PlantParams, name: str, values: Sequence[float]) -> list[float]:
    """Validated unstretched lengths as a list of floats (each finite and > 0)."""
    n = len(params.anchors_m)
    try:
        out = [float(v) for v in values]
    except (TypeError, ValueError):
        raise PlantError(f"{name} must be {n} numbers, got {values!r}") from None
    if len(out) != n:
        raise PlantError(f"{name} has {len(out)} values for {n} cables")
    for i, v in enumerate(out):
        if not (0.0 < v < math.inf):
            raise PlantError(f"{name} of cable {i + 1} must be finite and > 0, got {v!r}")
    return out


def _static_tensions(params: PlantParams, p: Vec3, l0: Sequence[float]) -> tuple[float, ...]:
    """Elastic tensions at pose `p` for unstretched lengths `l0` (no damping)."""
    out = []
    for (ax, ay, az), ea, l0_i in zip(params.anchors_m, params.ea_n, l0, strict=True):
        e = math.sqrt((ax - p[0]) ** 2 + (ay - p[1]) ** 2 + (az - p[2]) ** 2) - l0_i
        out.append(ea / l0_i * e if e > 0.0 else 0.0)
    return tuple(out)


def _force_and_stiffness(
    params: PlantParams, p: np.ndarray, l0: np.ndarray, k: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Net static force, tangent stiffness (= Hessian of the energy), energy and tensions."""
    d = np.asarray(params.anchors_m) - p
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    stretch = np.maximum(length - l0, 0.0)
    t = k * stretch
    u = d / length[:, None]
    force = t @ u
    force[2] -= params.weight_n
    taut = stretch > 0.0
    ut = u[taut]
    g = t[taut] / length[taut]
    stiff = (ut.T * (k[taut] - g)) @ ut + np.eye(3) * float(g.sum())
    energy = params.weight_n * float(p[2]) + 0.5 * float(np.dot(k, stretch * stretch))
    return force, stiff, energy, t


def _newton(
    params: PlantParams,
    l0: np.ndarray,
    k: np.ndarray,
    p: np.ndarray,
    tol: float,
    max_iterations: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, bool]:
    """Newton with a line search on the energy; returns (pose, force, tensions, its, converged)."""
    span = float(np.abs(np.asarray(params.anchors_m)).max() + l0.max())
    force, stiff, energy, t = _force_and_stiffness(params, p, l0, k)
    for iteration in range(max_iterations):
        residual = float(np.linalg.norm(force))
        if residual <= tol:
            return p, force, t, iteration, True
        # Levenberg-regularised Newton step (the stiffness is singular with no cable taut).
        scale = float(np.trace(stiff)) + params.weight_n / max(span, 1.0)
        mu = 1e-12 * scale
        while True:
            try:
                step = np.linalg.solve(stiff + mu * np.eye(3), force)
            except np.linalg.LinAlgError:
                step = None
            if step is not None and np.all(np.isfinite(step)) and float(force @ step) > 0.0:
                break
            mu = max(mu * 100.0, 1e-9 * scale)
            if mu > 1e12 * scale:
                return p, force, t, iteration, False
        # Accept a step that lowers the energy enough or, near the solution where the energy
        # change is below rounding, one that shrinks the residual.
        alpha = 1.0
        slope = float(force @ step)
        for _ in range(60):
            q = p + alpha * step
            f2, s2, e2, t2 = _force_and_stiffness(params, q, l0, k)
            if e2 <= energy - 1e-4 * alpha * slope or (
                float(np.linalg.norm(f2)) < (1.0 - 1e-4 * alpha) * residual
            ):
                break
            alpha *= 0.5
        else:
            return p, force, t, iteration, False
        p, force, stiff, energy, t = q, f2, s2, e2, t2
    return p, force, t, max_iterations, float(np.linalg.norm(force)) <= tol


_CONTINUATION_STRAIN = 0.01
"""First continuation stage: cables that stretch about this much under the full weight."""
_CONTINUATION_FACTOR = 100.0
"""Stiffness ratio between continuation stages."""


def equilibrium(
    params: PlantParams,
    unstretched_m: Sequence[float],
    guess_m: Sequence[float] | None = None,
    *,
    tol_n: float = 1e-9,
    max_iterations: int = 50,
) -> Equilibrium:
    """The static rest pose of the effector for the given unstretched cable lengths.

    Minimises the potential energy m g z + sum k_i max(0, L_i - L0_i)^2 / 2, which is convex in
    the pose, by Newton steps on the force balance with a line search (slack cables drop out of
    the force and the stiffness; with nothing taut the stiffness is regularised). Converged when
    the net force is below `tol_n` (raised to what rounding allows for very stiff cables).
    Where a cable tightens or slackens the force has a kink, and with cables very stiff for the
    weight Newton can creep along it; if it does not converge within `max_iterations` from the
    guess, it solves again by continuation: first with cables softened to stretch about 1 %
    under the weight, then stiffer by a factor of 100 per stage (each stage started from the
    last) up to the real stiffness. `guess_m` defaults to a point below the anchors' centroid
    where every cable is taut. With no gravity any pose with every cable slack is a rest pose
    (the one returned depends on the guess). Raises PlantError on bad inputs and
    EquilibriumError when no rest pose is found.
    """
    l0 = np.array(_lengths(params, "unstretched_m", unstretched_m))
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, int):
        raise PlantError(f"max_iterations must be an int >= 1, got {max_iterations!r}")
    if max_iterations < 1:
        raise PlantError(f"max_iterations must be an int >= 1, got {max_iterations!r}")
    ea = np.asarray(params.ea_n)
    k = ea / l0
    anchors = np.asarray(params.anchors_m)
    if guess_m is None:
        p0 = np.array([*anchors[:, :2].mean(axis=0), anchors[:, 2].min() - l0.max()])
    else:
        p0 = np.array(_vec3("guess_m", guess_m))
    span = float(np.abs(anchors).max() + l0.max())
    tol = max(_positive("tol_n", tol_n), 64.0 * _EPS * (params.weight_n + float(k.sum()) * span))
    p, force, t, iterations, ok = _newton(params, l0, k, p0, tol, max_iterations)
    total = iterations
    if not ok:
        p = p0
        factor = min(1.0, params.weight_n / _CONTINUATION_STRAIN / float(ea.min()))
        if factor <= 0.0:
            factor = 1.0
        while True:
            scaled = k * factor
            stage_tol = max(
                tol * factor, 64.0 * _EPS * (params.weight_n + float(scaled.sum()) * span)
            )
            p, force, t, iterations, ok = _newton(params, l0, scaled, p, stage_tol, max_iterations)
            total += iterations
            if factor >= 1.0:
                break
            factor = min(1.0, factor * _CONTINUATION_FACTOR)
    residual = float(np.linalg.norm(force))
    if not ok:
        raise EquilibriumError(
            f"no rest pose found in {total} iterations (residual {residual:.3g} N at {p.tolist()})"
        )
    pos = (float(p[0]), float(p[1]), float(p[2]))
    return Equilibrium(pos, tuple(float(x) for x in t), residual, total)


def unstretched_lengths(
    params: PlantParams, position_m: Sequence[float], tensions_n: Sequence[float]
) -> tuple[float, ...]:
    """Unstretched lengths that give cable tensions `tensions_n` with the effector at `position_m`.

    From t = EA / L0 * (L - L0): L0 = L * EA / (EA + t). If the tensions balance the weight
    (a statics solution) the effector is at rest there. Raises PlantError on a bad pose, a
    negative or non-finite tension, a wrong count, or the effector on an anchor.
    """
    p = _vec3("position_m", position_m)
    n = len(params.anchors_m)
    if len(tensions_n) != n:
        raise PlantError(f"tensions_n has {len(tensions_n)} values for {n} cables")
    out = []
    cables = zip(params.anchors_m, params.ea_n, tensions_n, strict=True)
    for i, ((ax, ay, az), ea, tension) in enumerate(cables):
        t = _non_negative(f"tension of cable {i + 1}", tension)
        length = math.sqrt((ax - p[0]) ** 2 + (ay - p[1]) ** 2 + (az - p[2]) ** 2)
        if length <= 0.0:
            raise PlantError(f"the effector is on anchor {i + 1}")
        out.append(length * ea / (ea + t))
    return tuple(out)


def _holding_tensions(
    params: PlantParams, position_m: Vec3, pretension_n: float = 0.0
) -> tuple[float, ...]:
    """A simple positive tension distribution holding the effector at rest at `position_m`.

    The minimum-norm solution of sum t_i u_i = m g e_z, moved along the null space (one
    redundant cable, N = 4) by the least amount that keeps every tension >= `pretension_n`.
    With three cables the solution is unique and must be >= 0 (the pre-tension cannot be
    chosen). With every anchor above the effector the null space trades tension between the
    cables (some gain, some lose: no internal loop can pull them all, since every cable's
    upward pull is carried by the weight), so the pre-tension that can be had is limited. A
    stand-in for a statics solver: more than one
    redundant cable is refused.
    Raises EquilibriumError when no such distribution exists (the pose is outside the
    cables' reach, or the cables are degenerate there).
    """
    anchors = np.asarray(params.anchors_m)
    d = anchors - np.asarray(position_m)
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    if np.any(length <= 0.0):
        raise PlantError("the effector is on an anchor")
    jac = (d / length[:, None]).T  # 3 x N, columns u_i
    wrench = np.array([0.0, 0.0, params.weight_n])
    _, sv, vt = np.linalg.svd(jac)
    rank = int(np.sum(sv > 1e-9 * sv[0]))
    t0 = np.linalg.pinv(jac, rcond=1e-9) @ wrench
    if float(np.linalg.norm(jac @ t0 - wrench)) > 1e-9 * max(params.weight_n, 1.0):
        raise EquilibriumError(f"the cables cannot hold the weight at {position_m}")
    nullity = jac.shape[1] - rank
    if nullity == 0:
        if float(t0.min()) < -1e-12 * params.weight_n:
            raise EquilibriumError(
                f"holding the effector at {position_m} needs a cable to push ({t0.tolist()})"
            )
        return tuple(max(0.0, float(x)) for x in t0)
    if nullity > 1:
        raise EquilibriumError(
            f"{nullity} redundant cables: pass the tensions from a statics solution"
        )
    null = vt[-1]
    lo, hi = -math.inf, math.inf
    for ti, ni in zip(t0.tolist(), null.tolist(), strict=True):
        if abs(ni) < 1e-12:
            if ti < pretension_n:
                lo, hi = math.inf, -math.inf
        elif ni > 0.0:
            lo = max(lo, (pretension_n - ti) / ni)
        else:
            hi = min(hi, (pretension_n - ti) / ni)
    if lo > hi:
        raise EquilibriumError(
            f"no tension distribution >= {pretension_n} N holds the effector at {position_m}"
        )
    alpha = min(max(0.0, lo), hi)
    return tuple(max(0.0, float(x)) for x in t0 + alpha * null)


class CablePlant:
    """The simulated robot: state (pose, velocity, tensions) and its time step.

    Build it at a pose with `CablePlant(params, position_m, unstretched_m)`, at rest with
    `CablePlant.at_rest` (the equilibrium of given lengths) or `CablePlant.at_pose` (lengths
    that hold a pose with statically consistent tensions), then call `step` every tick with the
    unstretched lengths the reels have paid out (e.g. ``reel.length_m(position_rev)`` per
    cable). Not thread-safe; one owner steps it.
    """

    __slots__ = (
        "_ax",
        "_ay",
        "_az",
        "_c",
        "_ea",
        "_gain",
        "_l0",
        "_mass",
        "_n",
        "_p",
        "_params",
        "_substeps",
        "_t",
        "_time_s",
        "_v",
        "_weight",
        "_zeta",
    )

    def __init__(
        self,
        params: PlantParams,
        position_m: Sequence[float],
        unstretched_m: Sequence[float],
        velocity_mps: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> None:
        """Place the effector at `position_m` moving at `velocity_mps`, with these lengths.

        Raises PlantError on a non-finite pose or velocity or bad lengths.
        """
        self._params = params
        self._ax = [a[0] for a in params.anchors_m]
        self._ay = [a[1] for a in params.anchors_m]
        self._az = [a[2] for a in params.anchors_m]
        self._ea = list(params.ea_n)
        self._n = len(params.anchors_m)
        self._mass = params.mass_kg
        self._weight = params.weight_n
        self._c = params.effector_damping_n_s_per_m
        self._zeta = params.cable_damping_ratio
        self._p = _vec3("position_m", position_m)
        self._v = _vec3("velocity_mps", velocity_mps)
        self._l0 = _lengths(params, "unstretched_m", unstretched_m)
        self._t = _static_tensions(params, self._p, self._l0)
        self._time_s = 0.0
        self._substeps = 0
        self._gain: tuple[Any, ...] | None = None

    @classmethod
    def at_rest(
        cls,
        params: PlantParams,
        unstretched_m: Sequence[float],
        guess_m: Sequence[float] | None = None,
    ) -> CablePlant:
        """A plant at rest at the equilibrium of `unstretched_m` (see `equilibrium`)."""
        eq = equilibrium(params, unstretched_m, guess_m)
        return cls(params, eq.position_m, unstretched_m)

    @classmethod
    def at_pose(
        cls,
        params: PlantParams,
        position_m: Sequence[float],
        tensions_n: Sequence[float] | None = None,
        *,
        pretension_n: float = 0.0,
    ) -> CablePlant:
        """A plant at rest at `position_m`, its lengths set so that the cables hold it there.

        `tensions_n` must balance the weight (a statics solution); without it a simple
        distribution is used: the minimum-norm one, shifted to keep every tension
        >= `pretension_n` (three or four cables only). Raises PlantError / EquilibriumError.
        """
        p = _vec3("position_m", position_m)
        if tensions_n is None:
            tensions_n = _holding_tensions(params, p, _non_negative("pretension_n", pretension_n))
        return cls(params, p, unstretched_lengths(params, p, tensions_n))

    @property
    def params(self) -> PlantParams:
        """The plant's parameters."""
        return self._params

    @property
    def position_m(self) -> Vec3:
        """Effector position (m)."""
        return self._p

    @property
    def velocity_mps(self) -> Vec3:
        """Effector velocity (m/s)."""
        return self._v

    @property
    def tensions_n(self) -> tuple[float, ...]:
        """Cable tensions (N, >= 0) at the current pose, from the last force evaluation."""
        return self._t

    @property
    def unstretched_m(self) -> tuple[float, ...]:
        """The unstretched lengths (m) last applied."""
        return tuple(self._l0)

    @property
    def time_s(self) -> float:
        """Simulated time since the plant was built (s)."""
        return self._time_s

    @property
    def substeps(self) -> int:
        """Sub-steps the last `step` took (0 before the first)."""
        return self._substeps

    def energy_j(self) -> float:
        """Kinetic + gravitational (zero at z = 0) + elastic energy (J) of the current state."""
        px, py, pz = self._p
        vx, vy, vz = self._v
        energy = 0.5 * self._mass * (vx * vx + vy * vy + vz * vz) + self._weight * pz
        for i in range(self._n):
            dx = self._ax[i] - px
            dy = self._ay[i] - py
            dz = self._az[i] - pz
            e = math.sqrt(dx * dx + dy * dy + dz * dz) - self._l0[i]
            if e > 0.0:
                energy += 0.5 * self._ea[i] / self._l0[i] * e * e
        return energy

    def settle(self, unstretched_m: Sequence[float] | None = None) -> Vec3:
        """Put the effector at rest at the equilibrium of these lengths (default: the current).

        Returns the rest position. Raises PlantError / EquilibriumError; the state is unchanged
        on error.
        """
        l0 = (
            self._l0
            if unstretched_m is None
            else _lengths(self._params, "unstretched_m", unstretched_m)
        )
        eq = equilibrium(self._params, l0, self._p)
        self._l0 = list(l0)
        self._p = eq.position_m
        self._v = (0.0, 0.0, 0.0)
        self._t = _static_tensions(self._params, self._p, self._l0)
        return self._p

    def pull_length_m(self, cable: int, tension_n: float, dt_s: float) -> float:
        """The unstretched length at which cable `cable` (0-based) pulls `tension_n` with the
        effector where its velocity takes it in `dt_s`, ``L0 = L EA / (EA + T)``: following the
        length the step starts at would lag one step behind, a drag of EA / L0 * dt (a reel in
        torque control, `ReelPlant`).  Raises nothing for a valid cable index."""
        ea = self._ea[cable]
        dx = self._ax[cable] - self._p[0]
        dy = self._ay[cable] - self._p[1]
        dz = self._az[cable] - self._p[2]
        vx, vy, vz = self._v
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        length -= (dx * vx + dy * vy + dz * vz) / length * dt_s
        return length * ea / (ea + tension_n)

    def _damping_gain(
        self, taut: Sequence[bool]
    ) -> tuple[tuple[float, float, float, float, float, float], list[float]]:
        """The ropes' damping gain G (`controller.core.vibration.rope_damping`) of the `taut`
        cables at the pose, as its upper triangle (xx, xy, xz, yy, yz, zz), and each cable's
        retardation time along itself, u_i^T G u_i (s; 0 for a slack one). Kept while the same
        cables are taut and neither the pose nor any unstretched length has moved by
        `GAIN_REUSE` of the shortest cable (the gain then changes by about as little)."""
        key = tuple(taut)
        state = (*self._p, *self._l0)
        kept = self._gain
        tol = GAIN_REUSE * min(self._l0)
        if (
            kept is not None
            and kept[0] == key
            and all(abs(a - b) < tol for a, b in zip(state, kept[1], strict=True))
        ):
            return kept[2], kept[3]
        g, beta = self._gain_now(taut)
        self._gain = (key, state, g, beta)
        return g, beta

    def _gain_now(
        self, taut: Sequence[bool]
    ) -> tuple[tuple[float, float, float, float, float, float], list[float]]:
        """`_damping_gain` computed afresh."""
        px, py, pz = self._p
        idx = [i for i in range(self._n) if taut[i]]
        d = np.array([(self._ax[i] - px, self._ay[i] - py, self._az[i] - pz) for i in idx])
        u = d / np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]
        k = np.array([self._ea[i] / self._l0[i] for i in idx])
        gm = rope_damping((u.T * k) @ u, self._mass, self._zeta)[1]  # K_a = sum k_i u_i u_i^T
        beta = [0.0] * self._n
        for i, b in zip(idx, np.einsum("ij,jk,ik->i", u, gm, u).tolist(), strict=True):
            beta[i] = b  # u_i^T G u_i
        g = gm.tolist()
        return (g[0][0], g[0][1], g[0][2], g[1][1], g[1][2], g[2][2]), beta

    def _plan_substeps(self, l0b: Sequence[float], dt_s: float) -> tuple[int, list[bool]]:
        """The sub-steps a step of `dt_s` to the lengths `l0b` takes (the stability bound in
        the module docstring) and which cables are taut at its start. Raises PlantError for a
        bad length, the effector on an anchor or more than `max_substeps`."""
        ax, ay, az, ea, l0a = self._ax, self._ay, self._az, self._ea, self._l0
        px, py, pz = self._p
        # Upper bound on the stiffest mode at the start pose, over all cables (see the docstring).
        kxx = kyy = kzz = kxy = kxz = kyz = geo = 0.0
        tens = self._t
        taut = [False] * self._n
        for i in range(self._n):
            lb = l0b[i]
            if not (0.0 < lb < math.inf):
                raise PlantError(
                    f"unstretched_m of cable {i + 1} must be finite and > 0, got {lb!r}"
                )
            la = l0a[i]
            dx = ax[i] - px
            dy = ay[i] - py
            dz = az[i] - pz
            d2 = dx * dx + dy * dy + dz * dz
            if d2 <= 0.0:
                raise PlantError(f"the effector is on anchor {i + 1}")
            s = ea[i] / (la if la < lb else lb) / d2
            kxx += s * dx * dx
            kyy += s * dy * dy
            kzz += s * dz * dz
            kxy += s * dx * dy
            kxz += s * dx * dz
            kyz += s * dy * dz
            if tens[i] > 0.0:
                geo += tens[i] / math.sqrt(d2)
                taut[i] = True
        axy = abs(kxy)
        axz = abs(kxz)
        ayz = abs(kyz)
        lam = min(
            kxx + kyy + kzz,
            max(kxx + axy + axz, kyy + axy + ayz, kzz + axz + ayz),
        )
        m = self._mass
        w2 = (lam + geo) / m
        gamma = 2.0 * self._zeta * math.sqrt(w2) + self._c / m
        h_max = _STABILITY / (gamma + math.sqrt(gamma * gamma + _STABILITY * w2))
        nsub = math.ceil(dt_s / h_max)
        if nsub > self._params.max_substeps:
            raise PlantError(
                f"a step of {dt_s} s needs {nsub} sub-steps (max_substeps "
                f"{self._params.max_substeps}): the cables are too stiff for the mass"
            )
        return nsub, taut

    def step(self, unstretched_m: Sequence[float], dt_s: float) -> Vec3:
        """Advance by `dt_s` while the unstretched lengths move linearly to `unstretched_m`.

        Returns the new effector position; velocity and tensions are in the properties.
        Raises PlantError on a non-positive or non-finite `dt_s`, bad lengths, the effector on
        an anchor, or when the stiffness would need more than `max_substeps` sub-steps;
        PlantDivergedError if the state stops being finite. On any error the state is left as
        it was before the step.
        """
        if not (0.0 < dt_s < math.inf):
            raise PlantError(f"dt_s must be finite and > 0, got {dt_s!r}")
        n = self._n
        l0a = self._l0
        try:
            l0b = [float(x) for x in unstretched_m]
        except (TypeError, ValueError):
            raise PlantError(f"unstretched_m must be {n} numbers, got {unstretched_m!r}") from None
        if len(l0b) != n:
            raise PlantError(f"unstretched_m has {len(l0b)} values for {n} cables")
        nsub, taut = self._plan_substeps(l0b, dt_s)
        px, py, pz = self._p
        vx, vy, vz = self._v
        c = self._c
        if self._zeta > 0.0 and any(taut):
            (g00, g01, g02, g11, g12, g22), beta = self._damping_gain(taut)
        else:
            g00 = g01 = g02 = g11 = g12 = g22 = 0.0
            beta = [0.0] * n
        h = dt_s / nsub
        inv_m = 1.0 / self._mass
        change = [lb - la for la, lb in zip(l0a, l0b, strict=True)]
        rate = [d / dt_s for d in change]
        cables = list(
            zip(self._ax, self._ay, self._az, self._ea, l0a, change, rate, beta, strict=True)
        )
        fz0 = -self._weight
        hh = 0.5 * h
        # Velocity Verlet (kick, drift, kick). The force is evaluated once per sub-step, at the
        # new position, with the unstretched lengths of that instant and, for the damping, the
        # half-step velocity (w); the first evaluation is at the start of the step.
        wx = vx
        wy = vy
        wz = vz
        j = 0
        while True:
            frac = j / nsub
            fx = -c * wx
            fy = -c * wy
            fz = fz0 - c * wz
            # sum k_i de_i/dt u_i over the cables the damping gain was built for
            sx = sy = sz = 0.0
            t_out = []
            for cx, cy, cz, ea_i, l0_start, l0_change, l0_rate, beta_i in cables:
                dx = cx - px
                dy = cy - py
                dz = cz - pz
                length = math.sqrt(dx * dx + dy * dy + dz * dz)
                l0 = l0_start + l0_change * frac
                e = length - l0
                if e > 0.0:
                    k = ea_i / l0
                    t = k * e
                    t_out.append(t)
                    s = t / length
                    fx += s * dx
                    fy += s * dy
                    fz += s * dz
                    if beta_i > 0.0:
                        # strain rate: dL/dt - dL0/dt, with dL/dt = -(d . v) / L
                        edot = -(dx * wx + dy * wy + dz * wz) / length - l0_rate
                        kd = k * edot
                        if kd * beta_i < -t:  # a rope slackening fast: its damping never pushes
                            kd = -t / beta_i
                        s = kd / length
                        sx += s * dx
                        sy += s * dy
                        sz += s * dz
                    continue
                t_out.append(0.0)
            fx += g00 * sx + g01 * sy + g02 * sz
            fy += g01 * sx + g11 * sy + g12 * sz
            fz += g02 * sx + g12 * sy + g22 * sz
            if j:
                vx = wx + hh * fx * inv_m
                vy = wy + hh * fy * inv_m
                vz = wz + hh * fz * inv_m
                if j == nsub:
                    break
            j += 1
            wx = vx + hh * fx * inv_m
            wy = vy + hh * fy * inv_m
            wz = vz + hh * fz * inv_m
            px += h * wx
            py += h * wy
            pz += h * wz
        if not math.isfinite(px + py + pz + vx + vy + vz + sum(t_out)):
            raise PlantDivergedError(
                f"the plant diverged within a step of {dt_s} s at t = {self._time_s} s"
            )
        self._p = (px, py, pz)
        self._v = (vx, vy, vz)
        self._t = tuple(t_out)
        self._l0 = l0b
        self._time_s += dt_s
        self._substeps = nsub
        return self._p


class ReelPlant:
    """One `CablePlant` driven by the motor positions of its reels: the effector couples them.

    Motor turns become unstretched cable lengths through each reel's model, ``L0_i =
    reel_i.length_m(position_rev_i) - stretch_i``, and each cable's tension becomes the motor
    torque that holds it, ``reel_i.torque_nm(position_rev_i, t_i)`` (work balance, see
    `controller.core.reel`). ``stretch_i`` is fixed when the plant is built: the effector rests
    at `position_m` with `tensions_n` (a statics solution; default the simple holding
    distribution of `CablePlant.at_pose`) while the reels are at `positions_rev`, so the
    reels' lengths are the geometric lengths there, as the controller's kinematics assume.
    Elsewhere the cables stretch as their tensions demand. `plant` replaces the plant built
    from `params` (heavy cables: a `controller.core.sag_plant.SagPlant` at rest at
    `position_m`, the tensions then being its own). Not thread-safe: one owner steps it.
    Raises PlantError / EquilibriumError on bad inputs, ValueError on a wrong number of reels.

    A reel in torque control (`step`'s `pulls_nm`) is an ideal torque source: its motor makes
    the torque it is told, which holds the tension ``T = reel.tension_n(turns, torque)``; the
    reel turns as the cable lets it. Each step, before the plant moves, its unstretched length
    goes to the one at which the cable pulls ``T`` where the effector's velocity takes it by the
    end of the step, ``L0 = L EA / (EA + T)`` (``T <= 0``: paid out), but no faster than its
    speed limit (the drive's vel_limit, as cable speed): a slack cable is wound in at that speed
    until it pulls, a pulled one eases out. So the effector feels constant forces along its
    cables, and the motor turns are read back from the lengths (`positions_rev`). No rotor
    inertia and no friction: a direct-drive reel on a drive whose current loop is far faster
    than the tick.
    """

    __slots__ = ("_positions", "_reels", "_stretch", "_torques", "plant")

    def __init__(
        self,
        params: PlantParams,
        reels: Sequence[ReelModel],
        position_m: Sequence[float],
        positions_rev: Sequence[float],
        tensions_n: Sequence[float] | None = None,
        plant: Any = None,
    ) -> None:
        if len(reels) != params.cables or len(positions_rev) != params.cables:
            raise ValueError(
                f"{params.cables} cables need as many reels and positions, got {len(reels)} "
                f"and {len(positions_rev)}"
            )
        self.plant = CablePlant.at_pose(params, position_m, tensions_n) if plant is None else plant
        self._reels = tuple(reels)
        positions = [_finite(f"positions_rev[{i}]", p) for i, p in enumerate(positions_rev)]
        self._stretch = [
            r.length_m(p) - l0
            for r, p, l0 in zip(self._reels, positions, self.plant.unstretched_m, strict=True)
        ]
        self._positions = positions
        self._torques = self._torques_now()

    def _torques_now(self) -> tuple[float, ...]:
        return tuple(
            r.torque_nm(p, t)
            for r, p, t in zip(self._reels, self._positions, self.plant.tensions_n, strict=True)
        )

    def step(
        self,
        positions_rev: Sequence[float],
        dt_s: float,
        pulls_nm: Sequence[float | None] | None = None,
        max_speeds_rps: Sequence[float] | None = None,
    ) -> tuple[float, ...]:
        """Move the reels to `positions_rev` over `dt_s`, step the plant; return each motor's
        torque (N m): the holding torque of its cable, or for a reel in torque control
        (`pulls_nm[i]` not None: the motor's torque) that torque, the reel turning as the
        class docstring says at most `max_speeds_rps[i]` (default: unlimited) and its
        `positions_rev[i]` ignored; read the turns back from `positions_rev`. Raises
        PlantError (bad input, a cable paid in past zero length, the plant diverging); the
        state is then unchanged."""
        reels = self._reels
        stretch = self._stretch
        n = len(reels)
        positions = [float(p) for p in positions_rev]
        if len(positions) != n:
            raise PlantError(f"{n} reels need as many positions, got {len(positions)}")
        l0 = [reels[i].length_m(positions[i]) - stretch[i] for i in range(n)]
        pulled: dict[int, float] = {}
        if pulls_nm is not None:
            for i, pull in enumerate(pulls_nm):
                if pull is None:
                    continue
                torque = _finite("pulls_nm", pull)
                speed = math.inf if max_speeds_rps is None else float(max_speeds_rps[i])
                positions[i], l0[i] = self._pull(i, torque, speed, dt_s)
                pulled[i] = torque
        self.plant.step(l0, dt_s)
        self._positions = positions
        torques = self._torques_now()
        if pulled:
            torques = tuple(pulled.get(i, t) for i, t in enumerate(torques))
        self._torques = torques
        return self._torques

    def _pull(
        self, i: int, torque_nm: float, max_speed_rps: float, dt_s: float
    ) -> tuple[float, float]:
        """Reel `i` in torque control: its turns and unstretched length after `dt_s` (class
        docstring). Raises PlantError on a reel that cannot turn (zero slope)."""
        reel = self._reels[i]
        turns = self._positions[i]
        try:
            tension = reel.tension_n(turns, torque_nm)
        except ValueError as exc:
            raise PlantError(f"reel {i + 1}: {exc}") from None
        l0 = reel.length_m(turns) - self._stretch[i]
        # a pulled cable follows the plant; paying out, nothing pulls back
        target = self.plant.pull_length_m(i, tension, dt_s) if tension > 0.0 else math.inf
        step = (
            abs(reel.length_rate_mps(turns, max_speed_rps)) * dt_s
            if max_speed_rps < math.inf
            else math.inf
        )
        change = target - l0
        if change > step:
            change = step
        elif change < -step:
            change = -step
        if not math.isfinite(change):
            return turns, l0  # unlimited and paying out: stays (nothing to follow)
        new_l0 = l0 + change
        try:
            new_turns = reel.position_rev(new_l0 + self._stretch[i])
        except ValueError:  # the spool cannot pay out that far: it stops where it is
            return turns, l0
        return new_turns, new_l0

    @property
    def positions_rev(self) -> tuple[float, ...]:
        """The motors' turns after the last step (the given ones, or where torque control
        turned them)."""
        return tuple(self._positions)

    def slip(self, cable: int, metres: float) -> None:
        """Let cable `cable` (0-based) slip `metres` off its drum (positive: paid out) without
        its motor turning, from the next step on: a fault the encoders cannot see. Raises
        IndexError for a cable that does not exist, PlantError for a non-finite length."""
        self._stretch[cable] -= _finite("metres", metres)

    @property
    def torques_nm(self) -> tuple[float, ...]:
        """The motors' holding torques (N m) after the last step."""
        return self._torques

    @property
    def tensions_n(self) -> tuple[float, ...]:
        """The cable tensions (N) after the last step."""
        return self.plant.tensions_n

    @property
    def position_m(self) -> Vec3:
        """The effector's position (m)."""
        return self.plant.position_m
