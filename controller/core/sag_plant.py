"""The physical plant with heavy cables: a damped point mass hanging on elastic catenaries.

Pure module (``math``, ``numpy`` for the 3x3 solves of the rest pose), no I/O, no threads.
The plant of ``controller.core.plant`` when its cables have mass (``PlantParams``'
``cable_mass_kg_per_m``): the same effector, damping and integration, but each cable pulls the
effector along its tangent with the end force of Irvine's elastic catenary
(``controller.core.catenary``) instead of along its chord, and the reel carries the tension at
its own end, which includes the weight of the cable.

Quasi-static cables
-------------------
Each cable takes its static catenary shape for the effector's position at every step; the
cable's own motion (its transverse waves, its inertia) is not simulated.  That is exact at rest,
which is where the accuracy of the controller is measured, and the controller's model is a
static one.  In motion it leaves out two things.  The cable's transverse modes are slow at this
scale, not fast: on the paper robot at (0, 0, 2) m with 5 kg, a 48 m line of 8.3 g/m under
121 N has its first mode at sqrt(T / mu) / (2 L) = 1.3 Hz, 3 mm steel (36 g/m, 177 N) 0.7 Hz,
against the effector's own modes on those cables of 1.4, 6.3 and 10 Hz (Dyneema) and 1.0, 4.2
and 6.8 Hz (steel); so the plant shows no cable swing nor its coupling with the effector's
sway, which in a real rig rings on after a move until air drag damps it.  And about a third of
each cable's mass moves with the effector (0.13 kg of Dyneema, 0.57 kg of steel per 48 m cable,
against 5 kg of payload), so the plant's transients are a few to ten per cent quicker than a
real rig's.

Step
----
At the start of every step each cable's catenary is solved exactly (``catenary.from_length``,
warm-started from the last step's end forces) at the effector's position and the cable's
unstretched length, with its stiffness: the flexibility of the catenary (the derivatives of its
reach by ``H`` and ``V0``) inverted, and the derivative of its end forces by the unstretched
length.  Within the step's sub-steps the end forces follow that linearisation in the cable's
span, rise and length, while the direction of the horizontal pull follows the exact geometry:
the step of ``CablePlant.step`` (velocity Verlet), with a Kelvin-Voigt damping ``beta`` times the
rate of change of the elastic end forces, ``beta = 2 zeta / omega`` with ``omega`` the step's
bound on the stiffest mode: that mode is damped at ``cable_damping_ratio``, softer ones in
proportion to their frequency (stiffness-proportional damping; the straight plant's ropes damp
every axial mode at that ratio, so at the default ratio the slow modes ring longer here than
there; the tests that wait for rest damp both critically).  The number of
sub-steps follows the stiffness bound ``sum_i trace(K_i) + H_i / span_i`` over the mass, as the
straight plant's bound does.  A cable whose linearised horizontal force falls to zero within a
step carries nothing until the next step solves it again (a slack cable; a heavy cable with any
span has a catenary and pulls).

The tensions the plant reports (``tensions_n``: what the reels carry) are those at the anchor
end; ``effector_tensions_n`` those at the effector.  The rest pose (``sag_equilibrium``) is
found by Newton on the effector's force balance with the exact catenary end forces and their
stiffness, started at the rest pose of the same cables without mass.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from controller.core import catenary
from controller.core.plant import (
    _STABILITY,
    CablePlant,
    Equilibrium,
    EquilibriumError,
    PlantDivergedError,
    PlantError,
    PlantParams,
    Vec3,
    equilibrium,
)

__all__ = ["SagPlant", "sag_equilibrium"]

_NO_CABLE = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

RESOLVE_M = 5e-3
"""The catenaries are solved afresh at the start of a step when the effector or a cable's
unstretched length has moved more than this since they last were (a move at 1 m/s: every
fifth millisecond); within it the linearisation about that solve stands, its force error
quadratic in the distance (a few millinewtons on the paper robot's cables)."""
RESOLVE_AT_REST_M = 1e-7
"""Below ``SLOW_MPS`` they are solved afresh once the state has moved more than this: the
effector comes to rest on exact catenaries, and at rest costs no solves."""
SLOW_MPS = 1e-3
"""An effector slower than this is coming to rest (``RESOLVE_AT_REST_M``)."""
MAX_LINEAR_STEP_S = 0.005
"""A longer step (a caller that stalled) is taken in pieces of at most this, each linearised
afresh."""


def _vec3(name: str, value: Sequence[float]) -> Vec3:
    try:
        x, y, z = (float(v) for v in value)
    except (TypeError, ValueError):
        raise PlantError(f"{name} must be 3 coordinates, got {value!r}") from None
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise PlantError(f"{name} must be finite, got {value!r}")
    return (x, y, z)


def _lengths(n: int, name: str, values: Sequence[float]) -> list[float]:
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


def _solve_cable(
    anchor: Vec3,
    p: Vec3,
    l0: float,
    w: float,
    c: float,
    guess: tuple[float, float] | None,
) -> tuple[float, ...]:
    """One cable at pose `p`: (H, V0, span, rise, ux, uy, K00, K01, K11, dH/dL0, dV0/dL0, T0)
    with (ux, uy) the horizontal unit vector toward the anchor and K the 2x2 stiffness of the
    end forces in (span, rise); `_NO_CABLE` for a slack one.  Raises PlantError when the
    effector is on the anchor or the catenary does not converge."""
    dx = anchor[0] - p[0]
    dy = anchor[1] - p[1]
    rise = anchor[2] - p[2]
    span = math.hypot(dx, dy)
    try:
        ends, r = catenary.from_length_and_reach(span, rise, l0, w, c, guess)
    except catenary.SlackCableError:
        return _NO_CABLE
    except catenary.CatenaryError as exc:
        raise PlantError(f"cable at {anchor}: {exc}") from None
    h, v0 = ends.h_n, ends.v0_n
    det = r.ds_dh * r.dr_dv - r.ds_dv * r.dr_dh
    if not (det > 0.0 and math.isfinite(det)):
        return _NO_CABLE
    k00 = r.dr_dv / det
    k01 = -r.ds_dv / det
    k11 = r.ds_dh / det
    gh = -(k00 * r.ds_dl + k01 * r.dr_dl)
    gv = -(k01 * r.ds_dl + k11 * r.dr_dl)
    if span > 0.0:
        ux, uy = dx / span, dy / span
    else:
        ux = uy = 0.0
    return (h, v0, span, rise, ux, uy, k00, k01, k11, gh, gv, ends.t0_n)


def _pulls(cab: Sequence[float]) -> bool:
    """True for a cable that pulls: with a horizontal force, or straight along the vertical
    with a vertical one (``_NO_CABLE``: slack)."""
    return cab[0] > 0.0 or (cab[2] == 0.0 and cab[1] != 0.0)


class SagPlant:
    """The simulated robot with heavy cables: the interface of `CablePlant` (state, `step`,
    `settle`), the cables hanging in catenaries (module docstring).

    Build it at a pose with `SagPlant(params, position_m, unstretched_m)`, at rest with
    `SagPlant.at_rest` or `SagPlant.at_pose` (the cables' horizontal forces of a statics
    solution with sag).  Not thread-safe; one owner steps it.  Raises PlantError on bad input.
    """

    __slots__ = (
        "_anchors",
        "_c",
        "_cables",
        "_l0",
        "_lin",
        "_p",
        "_params",
        "_substeps",
        "_t",
        "_t0",
        "_time_s",
        "_v",
        "_w",
    )

    def __init__(
        self,
        params: PlantParams,
        position_m: Sequence[float],
        unstretched_m: Sequence[float],
        velocity_mps: Sequence[float] = (0.0, 0.0, 0.0),
    ) -> None:
        """Place the effector at `position_m` moving at `velocity_mps`, with these lengths.

        Raises PlantError on a non-finite pose or velocity, bad lengths, or a catenary that
        cannot be solved there.
        """
        self._params = params
        self._anchors = params.anchors_m
        self._w = params.cable_weight_n_per_m
        self._c = tuple(1.0 / ea for ea in params.ea_n)
        self._p = _vec3("position_m", position_m)
        self._v = _vec3("velocity_mps", velocity_mps)
        self._l0 = _lengths(params.cables, "unstretched_m", unstretched_m)
        self._cables = self._solve(self._p, self._l0)
        self._lin: tuple[Vec3, list[float]] = (self._p, list(self._l0))
        self._t = self._anchor_tensions(self._cables, self._l0)
        self._t0 = tuple(cable[11] for cable in self._cables)
        self._time_s = 0.0
        self._substeps = 0

    def _solve(self, p: Vec3, l0: Sequence[float]) -> list[tuple[float, ...]]:
        """Every cable's catenary at `p`, started from the last solution's linearisation
        moved to `p` and `l0` (one Newton step then meets the tolerance)."""
        old = getattr(self, "_cables", None)
        lin = getattr(self, "_lin", None)
        out = []
        for i, anchor in enumerate(self._anchors):
            guess = None
            if old is not None and lin is not None and old[i][0] > 0.0:
                h0, v0, span0, rise0, _ux, _uy, k00, k01, k11, gh, gv, _t0 = old[i]
                ds = math.hypot(anchor[0] - p[0], anchor[1] - p[1]) - span0
                dr = anchor[2] - p[2] - rise0
                dl = l0[i] - lin[1][i]
                h = h0 + k00 * ds + k01 * dr + gh * dl
                guess = (h, v0 + k01 * ds + k11 * dr + gv * dl) if h > 0.0 else (h0, v0)
            out.append(_solve_cable(anchor, p, l0[i], self._w[i], self._c[i], guess))
        return out

    def _anchor_tensions(
        self, cables: Sequence[tuple[float, ...]], l0: Sequence[float]
    ) -> tuple[float, ...]:
        return tuple(
            math.hypot(cab[0], cab[1] + w * length) if cab[0] > 0.0 or cab[1] != 0.0 else 0.0
            for cab, w, length in zip(cables, self._w, l0, strict=True)
        )

    @classmethod
    def at_rest(
        cls,
        params: PlantParams,
        unstretched_m: Sequence[float],
        guess_m: Sequence[float] | None = None,
    ) -> SagPlant:
        """A plant at rest at the equilibrium of `unstretched_m` (`sag_equilibrium`)."""
        eq = sag_equilibrium(params, unstretched_m, guess_m)
        return cls(params, eq.position_m, unstretched_m)

    @classmethod
    def at_pose(
        cls, params: PlantParams, position_m: Sequence[float], horizontal_n: Sequence[float]
    ) -> SagPlant:
        """A plant at `position_m` whose cable `i` pulls with the horizontal force
        `horizontal_n[i]`, its unstretched length that of the catenary with that force
        (``catenary.from_horizontal_force``).  At rest when the forces are those of a statics
        solution with sag (the end forces balance the weight).  Raises PlantError for a bad
        pose or count, a force that is not positive and finite or cannot hold its cable."""
        p = _vec3("position_m", position_m)
        if len(horizontal_n) != params.cables:
            raise PlantError(
                f"horizontal_n has {len(horizontal_n)} values for {params.cables} cables"
            )
        lengths = []
        for i, ((ax, ay, az), h, w, ea) in enumerate(
            zip(
                params.anchors_m,
                horizontal_n,
                params.cable_weight_n_per_m,
                params.ea_n,
                strict=True,
            )
        ):
            try:
                ends = catenary.from_horizontal_force(
                    math.hypot(ax - p[0], ay - p[1]), az - p[2], h, w, 1.0 / ea
                )
            except catenary.CatenaryError as exc:
                raise PlantError(f"cable {i + 1}: {exc}") from None
            lengths.append(ends.unstretched_m)
        return cls(params, p, lengths)

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
        """Cable tensions at the anchor end (N, >= 0: what the reels carry), from the last
        force evaluation."""
        return self._t

    @property
    def effector_tensions_n(self) -> tuple[float, ...]:
        """Cable tensions at the effector end (N) at the start of the last step."""
        return self._t0

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

    def net_force_n(self) -> Vec3:
        """The static force on the effector at its pose: the cables' end forces (solved
        exactly there) and its weight (zero at rest).  Raises PlantError where a catenary
        cannot be solved."""
        fx = fy = 0.0
        fz = -self._params.weight_n
        for h, v0, _s, _r, ux, uy, *_ in self._solve(self._p, self._l0):
            fx += h * ux
            fy += h * uy
            fz += v0
        return (fx, fy, fz)

    def _forces_now(self, cable: int, dt_s: float = 0.0) -> tuple[float, float]:
        """(H, V0) of cable `cable` by the step's linearisation, at the effector's pose (moved
        on by its velocity for `dt_s`) and the cable's present unstretched length."""
        cab = self._cables[cable]
        h, v0, span0, rise0, _ux, _uy, k00, k01, k11, gh, gv, _t0 = cab
        if not _pulls(cab):
            return 0.0, 0.0
        ax, ay, az = self._anchors[cable]
        px, py, pz = self._p
        vx, vy, vz = self._v
        px, py, pz = px + vx * dt_s, py + vy * dt_s, pz + vz * dt_s
        ds = math.hypot(ax - px, ay - py) - span0
        dr = az - pz - rise0
        dl = self._l0[cable] - self._lin[1][cable]
        return h + k00 * ds + k01 * dr + gh * dl, v0 + k01 * ds + k11 * dr + gv * dl

    def settle(self, unstretched_m: Sequence[float] | None = None) -> Vec3:
        """Put the effector at rest at the equilibrium of these lengths (default: the current).

        Returns the rest position. Raises PlantError / EquilibriumError; the state is unchanged
        on error.
        """
        l0 = (
            self._l0
            if unstretched_m is None
            else _lengths(self._params.cables, "unstretched_m", unstretched_m)
        )
        eq = sag_equilibrium(self._params, l0, self._p)
        self._cables = self._solve(eq.position_m, l0)
        self._lin = (eq.position_m, list(l0))
        self._l0 = list(l0)
        self._p = eq.position_m
        self._v = (0.0, 0.0, 0.0)
        self._t = self._anchor_tensions(self._cables, self._l0)
        self._t0 = tuple(cable[11] for cable in self._cables)
        return self._p

    def pull_length_m(self, cable: int, tension_n: float, dt_s: float) -> float:
        """The unstretched length at which cable `cable` (0-based) would carry `tension_n` at
        its anchor end, the effector where its velocity takes it in `dt_s`: one Newton step
        on the anchor tension from the cable's last solution (a reel in torque control
        follows it step by step).  Raises nothing for a valid cable index."""
        gh, gv = self._cables[cable][9], self._cables[cable][10]
        l0 = self._l0[cable]
        w = self._w[cable]
        h1, v0 = self._forces_now(cable, dt_s)
        if h1 <= 0.0 and not _pulls(self._cables[cable]):
            return -math.inf  # slack: wind in until it pulls
        h1 = max(h1, 0.0)
        v1 = v0 + w * l0
        t1 = math.hypot(h1, v1)
        # d T1 / d L0 = (H dH/dL0 + V1 (dV0/dL0 + w)) / T1
        slope = (h1 * gh + v1 * (gv + w)) / t1
        if not slope < 0.0:
            return l0
        return l0 + (tension_n - t1) / slope

    def step(self, unstretched_m: Sequence[float], dt_s: float) -> Vec3:
        """Advance by `dt_s` while the unstretched lengths move linearly to `unstretched_m`.

        Returns the new effector position. Raises PlantError on a non-positive or non-finite
        `dt_s`, bad lengths, a catenary that cannot be solved, or when the stiffness would
        need more than `max_substeps` sub-steps; PlantDivergedError if the state stops being
        finite. On any error the state is left as it was before the step.
        """
        if not (0.0 < dt_s < math.inf):
            raise PlantError(f"dt_s must be finite and > 0, got {dt_s!r}")
        n = self._params.cables
        l0b = _lengths(n, "unstretched_m", unstretched_m)
        chunks = math.ceil(dt_s / MAX_LINEAR_STEP_S)
        if chunks > 1:  # a long step (a stalled caller): linearised no longer than that
            state = (self._cables, self._lin, self._p, self._v, self._t, self._t0, self._l0)
            start = list(self._l0)
            try:
                for k in range(1, chunks + 1):
                    f = k / chunks
                    self._step(
                        [a + (b - a) * f for a, b in zip(start, l0b, strict=True)], dt_s / chunks
                    )
            except PlantError:
                self._cables, self._lin, self._p, self._v, self._t, self._t0, self._l0 = state
                raise
            self._time_s += dt_s - dt_s / chunks * chunks  # rounding only
            return self._p
        return self._step(l0b, dt_s)

    def _step(self, l0b: list[float], dt_s: float) -> Vec3:
        """`step` within ``MAX_LINEAR_STEP_S``: the catenaries solved afresh when the effector
        or a length moved more than ``RESOLVE_M`` since they were (module docstring)."""
        l0a = self._l0
        px, py, pz = self._p
        lin_p, lin_l0 = self._lin
        moved = max(
            math.dist(lin_p, self._p),
            max(abs(a - b) for a, b in zip(lin_l0, l0a, strict=True)),
            max(abs(a - b) for a, b in zip(l0a, l0b, strict=True)),
        )
        vx, vy, vz = self._v
        slow = vx * vx + vy * vy + vz * vz < SLOW_MPS * SLOW_MPS
        if moved > RESOLVE_M or (slow and moved > RESOLVE_AT_REST_M):
            cables = self._solve(self._p, l0a)
            lin_l0 = list(l0a)
            lin_p = self._p
        else:
            cables = self._cables
        params = self._params
        m = params.mass_kg
        c = params.effector_damping_n_s_per_m
        zeta = params.cable_damping_ratio
        stiff = 0.0
        for cab in cables:
            if _pulls(cab):
                stiff += cab[6] + cab[8] + (cab[0] / cab[2] if cab[2] > 0.0 else 0.0)
        w2 = stiff / m
        if not w2 > 0.0:
            w2 = 1e-12
        om = math.sqrt(w2)
        gamma = 2.0 * zeta * om + c / m
        h_max = _STABILITY / (gamma + math.sqrt(gamma * gamma + _STABILITY * w2))
        nsub = math.ceil(dt_s / h_max)
        if nsub > params.max_substeps:
            raise PlantError(
                f"a step of {dt_s} s needs {nsub} sub-steps (max_substeps "
                f"{params.max_substeps}): the cables are too stiff for the mass"
            )
        beta = 2.0 * zeta / om
        h = dt_s / nsub
        hh = 0.5 * h
        inv_m = 1.0 / m
        fz0 = -params.weight_n
        rows = [
            (
                self._anchors[i][0],
                self._anchors[i][1],
                self._anchors[i][2],
                cab,
                l0a[i],
                l0a[i] - lin_l0[i],
                l0b[i] - l0a[i],
                (l0b[i] - l0a[i]) / dt_s,
                self._w[i],
            )
            for i, cab in enumerate(cables)
            if _pulls(cab)
        ]
        slack = [i for i, cab in enumerate(cables) if not _pulls(cab)]
        vx, vy, vz = self._v
        wx, wy, wz = vx, vy, vz
        j = 0
        t_out: list[float] = []
        while True:
            frac = j / nsub
            fx = -c * wx
            fy = -c * wy
            fz = fz0 - c * wz
            t_out = []
            for ax, ay, az, cab, l0_start, l0_off, l0_change, l0_rate, w in rows:
                h0, v00, span0, rise0, _ux, _uy, k00, k01, k11, gh, gv, _t0 = cab
                dx = ax - px
                dy = ay - py
                span = math.sqrt(dx * dx + dy * dy)
                ds = span - span0
                dr = az - pz - rise0
                dl = l0_off + l0_change * frac
                hl = h0 + k00 * ds + k01 * dr + gh * dl
                # rates of span and rise at the half-step velocity
                sd = -(dx * wx + dy * wy) / span if span > 0.0 else 0.0
                rd = -wz
                ht = hl + beta * (k00 * sd + k01 * rd + gh * l0_rate)
                vt = (
                    v00
                    + k01 * ds
                    + k11 * dr
                    + gv * dl
                    + beta * (k01 * sd + k11 * rd + gv * l0_rate)
                )
                if span > 0.0 and hl > 0.0 and ht > 0.0:
                    s = ht / span
                    fx += s * dx
                    fy += s * dy
                elif not (span == 0.0 and h0 == 0.0 and vt != 0.0):
                    t_out.append(0.0)  # slack until the next solve
                    continue
                else:
                    ht = 0.0  # straight along the vertical: no horizontal pull
                fz += vt
                t_out.append(math.hypot(ht, vt + w * (l0_start + l0_change * frac)))
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
        tensions = list(t_out)
        for i in slack:
            tensions.insert(i, 0.0)
        self._cables = cables
        self._lin = (lin_p, lin_l0)
        self._p = (px, py, pz)
        self._v = (vx, vy, vz)
        self._t = tuple(tensions)
        self._t0 = tuple(cab[11] for cab in cables)
        self._l0 = l0b
        self._time_s += dt_s
        self._substeps = nsub
        return self._p


def _net(params: PlantParams, cables: Sequence[tuple[float, ...]]) -> tuple[np.ndarray, np.ndarray]:
    """Net static force on the effector and its stiffness matrix (-dF/dP, symmetric)."""
    force = np.array([0.0, 0.0, -params.weight_n])
    stiff = np.zeros((3, 3))
    for h, v0, span, _r, ux, uy, k00, k01, k11, _gh, _gv, t0 in cables:
        if not (h > 0.0 or v0 != 0.0):
            continue
        force += (h * ux, h * uy, v0)
        u = np.array([ux, uy, 0.0])
        z = np.array([0.0, 0.0, 1.0])
        stiff += k00 * np.outer(u, u) + k01 * (np.outer(u, z) + np.outer(z, u))
        stiff += k11 * np.outer(z, z)
        if span > 0.0:
            stiff += h / span * (np.diag([1.0, 1.0, 0.0]) - np.outer(u, u))
        elif t0 > 0.0:  # vertical: its sideways stiffness is k00 in every horizontal way
            stiff += k00 * np.diag([1.0, 1.0, 0.0])
    return force, stiff


def sag_equilibrium(
    params: PlantParams,
    unstretched_m: Sequence[float],
    guess_m: Sequence[float] | None = None,
    *,
    tol_n: float = 1e-9,
    max_iterations: int = 100,
) -> Equilibrium:
    """The static rest pose of the effector on catenary cables of unstretched lengths
    `unstretched_m`: Newton on the force balance with the exact end forces and their stiffness,
    a line search on the net force.  Starts at `guess_m`, or at the rest pose of the same
    cables without mass (``plant.equilibrium``).  Converged when the net force is below
    `tol_n` (raised to what rounding allows).  Tensions are those at the anchor end.  Raises
    PlantError on bad inputs and EquilibriumError when no rest pose is found.
    """
    n = params.cables
    l0 = _lengths(n, "unstretched_m", unstretched_m)
    if guess_m is None:
        straight = PlantParams(params.anchors_m, params.ea_n, params.mass_kg)
        p = np.array(equilibrium(straight, l0).position_m)
    else:
        p = np.array(_vec3("guess_m", guess_m))
    w = params.cable_weight_n_per_m
    c = [1.0 / ea for ea in params.ea_n]
    # the catenaries are solved to about 1e-10 m: their end forces to that times EA / L0
    tol = max(
        tol_n,
        1e-10 * (params.weight_n + sum(ea / x for ea, x in zip(params.ea_n, l0, strict=True))),
    )

    def solve(q: np.ndarray, old: list[tuple[float, ...]] | None) -> list[tuple[float, ...]]:
        pt = (float(q[0]), float(q[1]), float(q[2]))
        return [
            _solve_cable(
                a,
                pt,
                l0[i],
                w[i],
                c[i],
                None if old is None or old[i][0] <= 0.0 else (old[i][0], old[i][1]),
            )
            for i, a in enumerate(params.anchors_m)
        ]

    cables = solve(p, None)
    force, stiff = _net(params, cables)
    norm = float(np.linalg.norm(force))
    for it in range(max_iterations):
        if norm <= tol:
            return Equilibrium(
                (float(p[0]), float(p[1]), float(p[2])),
                tuple(
                    math.hypot(cab[0], cab[1] + wi * li)
                    for cab, wi, li in zip(cables, w, l0, strict=True)
                ),
                norm,
                it,
            )
        try:
            step = np.linalg.solve(stiff + 1e-12 * np.trace(stiff) * np.eye(3), force)
        except np.linalg.LinAlgError:
            break
        if not np.all(np.isfinite(step)):
            break
        alpha = 1.0
        for _ in range(40):
            q = p + alpha * step
            try:
                cab2 = solve(q, cables)
            except PlantError:
                alpha *= 0.5
                continue
            f2, s2 = _net(params, cab2)
            n2 = float(np.linalg.norm(f2))
            if n2 < norm or n2 <= tol:
                break
            alpha *= 0.5
        else:
            break
        p, cables, force, stiff, norm = q, cab2, f2, s2, n2
    raise EquilibriumError(
        f"no rest pose found on the catenaries (residual {norm:.3g} N at {p.tolist()})"
    )


def plant_at_pose(
    params: PlantParams,
    position_m: Sequence[float],
    tensions_n: Sequence[float] | None = None,
    horizontal_n: Sequence[float] | None = None,
) -> CablePlant | SagPlant:
    """The plant of `params` at rest at `position_m`: `SagPlant.at_pose` with the horizontal
    forces `horizontal_n` when the cables have mass (required then), else
    `CablePlant.at_pose` with `tensions_n`.  Raises PlantError / EquilibriumError."""
    if params.sags:
        if horizontal_n is None:
            raise PlantError("a plant with heavy cables needs their horizontal forces")
        return SagPlant.at_pose(params, position_m, horizontal_n)
    return CablePlant.at_pose(params, position_m, tensions_n)
