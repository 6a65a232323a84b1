"""Statics with the cables' weight: the end forces of heavy, elastic cables that hold the payload.

Pure module (``math``; the statics and the catenary of this package), no I/O, no threads.

Model
-----
Each cable hangs in an elastic catenary (``controller.core.catenary``) from its anchor to the
effector.  It pulls the effector along its tangent there, not along its chord, and its anchor
end carries more than its effector end: the tension grows along the cable by its weight per
metre times the height it climbs (exactly so for an inextensible cable).  The tension
distribution that holds the payload is the statics' one (``controller.core.statics``: the
equilibrium farthest from the tension limits) along the cables' tangents at the effector; the
tangents depend on the tensions.  Unknowns: each cable's tangent elevation at the effector,
``theta_i`` (its bearing is the anchor's).  Along those tangents the statics give each cable's
end force, whose horizontal part ``H_i`` fixes the cable's catenary between its ends (closed
form inextensible, a Newton step or two for the stretch: ``catenary.from_horizontal_force``),
whose own tangent at the effector must be ``theta_i``.  ``SagStatics.solve`` solves that by
Newton on the ``theta_i`` (the tensions' derivative by the tangents by forward differences of
the statics, the catenaries' analytically), from the chords or from a solution nearby (its sag
angles carried over).  A plain fixed point "tangents -> tensions -> tangents" contracts only by
about the ratio of the sag angle to the chord's angle: 10 to 12 passes to 1e-9 rad for 4 mm
Dyneema on the paper robot at 5 kg, 46 to 92 for 3 mm steel; Newton takes two or three steps.

The answer (``SagSolution``): each cable's end forces, the tension at both ends (``t0`` at the
effector, ``t1`` at the anchor: what the reel, ``max_tension_n`` and the motor's torque limit
see), the tangents and the unstretched lengths the reels must pay out (the IPK with sag and
stretch).  The tension rule with sag (``sag_plan.SagTensionCheck``) keeps ``min_tension_n`` at
the effector end (the low end of a cable that climbs to its anchor) and ``max_tension_n`` at
the anchor end; the distribution is the statics' one for the effector-end tensions, so the
anchor end's margin is smaller by at most the cable's weight over its rise (2.7 N for 3 mm
steel 7.6 m up).  Where a cable's force at the effector would not be a pull (the statics give
it no tension, or too little for its weight over its span) there is no catenary: ``SagError``
names the cable (it would hang slack).

With no cable weight this is the straight-cable statics exactly (the catenary of a massless
cable is its chord; no Newton step).

Thread-safety: ``SagStatics`` is immutable after construction (every solve is a pure function
of its inputs).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

from controller.core import catenary
from controller.core.statics import (
    CableStatics,
    SingularConfiguration,
    StaticsError,
    StaticsInputError,
)

__all__ = [
    "GUESS_REUSE_M",
    "JACOBIAN_REUSE_M",
    "MAX_SAG_ITERATIONS",
    "SAG_TOL",
    "SagError",
    "SagSolution",
    "SagStatics",
]

Vec3 = tuple[float, float, float]
Matrix = tuple[tuple[float, ...], ...]
Newton = tuple[Matrix, Matrix, tuple[float, ...]]
"""The Newton matrix J of a solve, the statics' dt/dtheta and the catenaries' d theta'/dH."""

SAG_TOL = 1e-9
"""The solve has converged when every tangent at the effector is within this (rad) of its
catenary's."""
GUESS_REUSE_M = 0.25
"""A solve starts from a solution within this distance (its sag angles and, within
``JACOBIAN_REUSE_M``, its Newton matrix), farther from the chords.  Where the far cables sag
deep the statics with sag can have a second self-consistent distribution, one cable hanging
much deeper (at (-32, -2.5, 5.2) m with 3 mm steel and 5 kg, 0.29 m more of it paid out, the
margin 67 N against 84 N): from the chords Newton finds the tauter one, and a solve that follows
its neighbours in small steps stays on it, where one started a metre away may not."""
JACOBIAN_REUSE_M = 0.05
"""A solve started from a solution within this distance takes its first Newton step with that
solution's matrix (no finite differences)."""
MAX_SAG_ITERATIONS = 60
"""Most Newton steps of one solve."""
FIXED_POINT_PASSES = 300
"""Most passes of the fixed point a solve falls back to where Newton stalls (a kink of the
planned distribution): it contracts by about the ratio of the sag angle to the chord's, 10 to
100 passes."""


class SagError(StaticsError):
    """No tension distribution with sag: a cable's end force would not be a pull (it would hang
    slack), or the iteration did not converge."""


@dataclass(frozen=True, slots=True)
class SagSolution:
    """The cables' end forces that hold the payload at one pose, with their weight.

    Per cable (cable order): ``chords_m`` the straight-line lengths, ``paid_out_m`` the
    unstretched lengths (what the reels pay out), ``horizontal_n`` ``H``, ``directions`` the
    unit tangent at the effector (the direction it pulls), ``effector_tensions_n`` ``t0``,
    ``anchor_tensions_n`` ``t1``.  ``margin_n``: the smallest of ``t0 - t_min`` and ``t_max -
    t1`` over the cables (negative: a limit is broken), ``limiting_cable`` (0-based) and
    ``limiting_bound`` ("min": at the effector end, "max": at the anchor end) where it is;
    ``iterations`` the passes taken.
    """

    position_m: Vec3
    chords_m: tuple[float, ...]
    paid_out_m: tuple[float, ...]
    horizontal_n: tuple[float, ...]
    directions: tuple[Vec3, ...]
    effector_tensions_n: tuple[float, ...]
    anchor_tensions_n: tuple[float, ...]
    margin_n: float
    limiting_cable: int
    limiting_bound: Literal["min", "max"]
    iterations: int
    newton: Newton | None = field(default=None, compare=False, repr=False)
    """The last Newton matrix of the solve (J, dt/dtheta, d theta'/dH), for the gradients and
    for a solve started from this one."""


def _solve_along(statics: CableStatics, u: list[Vec3], weight_n: float) -> tuple[float, ...]:
    """The statics' tension distribution (farthest from the limits) for cables pulling along
    the directions `u` that hold a weight `weight_n` (``CableStatics.solve_directions``).
    Raises ``SingularConfiguration`` as the statics do (``StaticsInputError`` for directions
    that are not unit vectors, which the tangents always are)."""
    return statics.solve_directions(u, (0.0, 0.0, weight_n)).tensions_n


class SagStatics:
    """Statics with the cables' weight for one robot and payload (module docstring).

    `statics` gives the anchors and the tension limits, `weight_n_per_m` each cable's weight
    per metre (N/m; 0 = massless), `ea_n` each cable's EA (None = inextensible).  Raises
    ``StaticsInputError`` for a wrong count, a negative or non-finite weight, an EA not finite
    and > 0, or a non-positive mass.
    """

    __slots__ = ("_anchors", "_c", "_w", "mass_kg", "n", "statics", "weight_n")

    def __init__(
        self,
        statics: CableStatics,
        mass_kg: float,
        weight_n_per_m: Sequence[float],
        ea_n: Sequence[float | None],
    ) -> None:
        n = statics.n_cables
        if len(weight_n_per_m) != n or len(ea_n) != n:
            raise StaticsInputError(
                f"{n} cables need as many weights and EAs, got {len(weight_n_per_m)} and "
                f"{len(ea_n)}"
            )
        w = []
        for i, v in enumerate(weight_n_per_m):
            f = float(v)
            if not (math.isfinite(f) and f >= 0.0):
                raise StaticsInputError(f"cable {i + 1}: weight per metre must be >= 0, got {v!r}")
            w.append(f)
        c = []
        for i, e in enumerate(ea_n):
            if e is None:
                c.append(0.0)
                continue
            f = float(e)
            if not (math.isfinite(f) and f > 0.0):
                raise StaticsInputError(f"cable {i + 1}: EA must be finite and > 0, got {e!r}")
            c.append(1.0 / f)
        m = float(mass_kg)
        if not (math.isfinite(m) and m > 0.0):
            raise StaticsInputError(f"mass_kg must be finite and > 0, got {mass_kg!r}")
        self.statics = statics
        self.n = n
        self.mass_kg = m
        self.weight_n = m * 9.80665
        self._w = tuple(w)
        self._c = tuple(c)
        self._anchors = statics._anchors_t

    @property
    def weight_n_per_m(self) -> tuple[float, ...]:
        """Each cable's weight per metre (N/m)."""
        return self._w

    def solve(self, point_m: Sequence[float], guess: SagSolution | None = None) -> SagSolution:
        """The end forces of the cables that hold the payload at `point_m` (module docstring),
        starting from the tangents of `guess` (a solution within ``GUESS_REUSE_M``) or from
        the chords.

        Raises ``StaticsInputError`` for a bad point, ``SingularConfiguration`` where the
        statics have no distribution (the point at an anchor, above every anchor, tangents
        that do not span space) and ``SagError`` when a cable would hang slack or the
        iteration does not converge (a solve from `guess` that fails is tried again from the
        chords).
        """
        if guess is None or not (
            len(point_m) == 3 and math.dist(guess.position_m, point_m) <= GUESS_REUSE_M
        ):
            return self._solve(point_m, None)
        try:
            return self._solve(point_m, guess)
        except SagError:
            return self._solve(point_m, None)

    def _solve(self, point_m: Sequence[float], guess: SagSolution | None) -> SagSolution:
        """``solve`` from `guess` (or the chords) once."""
        if len(point_m) != 3:
            raise StaticsInputError(f"point_m needs 3 coordinates, got {len(point_m)}")
        px, py, pz = float(point_m[0]), float(point_m[1]), float(point_m[2])
        if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
            raise StaticsInputError(f"point_m ({px}, {py}, {pz}) is not finite")
        spans = []
        rises = []
        chords = []
        horiz: list[tuple[float, float]] = [(0.0, 0.0)] * self.n
        for i, (ax, ay, az) in enumerate(self._anchors):
            dx, dy, dz = ax - px, ay - py, az - pz
            s = math.hypot(dx, dy)
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            if not d > 1e-9:
                raise SingularConfiguration(
                    f"P = ({px:.6g}, {py:.6g}, {pz:.6g}) m is at anchor {i + 1}: cable {i + 1} "
                    "has no direction"
                )
            spans.append(s)
            rises.append(dz)
            chords.append(d)
            horiz[i] = (dx / s, dy / s) if s > 0.0 else (0.0, 0.0)
        where = (px, py, pz)
        theta = [math.atan2(rises[i], spans[i]) for i in range(self.n)]
        if guess is not None and len(guess.directions) == self.n:
            # the guess's sag angles (tangent below chord), moved to this pose
            gx, gy, gz = guess.position_m
            start = list(theta)
            for i, dg in enumerate(guess.directions):
                ax, ay, az = self._anchors[i]
                chord = math.atan2(az - gz, math.hypot(ax - gx, ay - gy))
                start[i] += math.atan2(dg[2], math.hypot(dg[0], dg[1])) - chord
            try:
                t, ends, res = self._pass(start, spans, rises, horiz, where)
                theta = start
            except (SagError, SingularConfiguration):
                t, ends, res = self._pass(theta, spans, rises, horiz, where)
        else:
            t, ends, res = self._pass(theta, spans, rises, horiz, where)
        norm = max(abs(r) for r in res)
        # A nearby solution's Newton matrix serves the first step (no finite differences).
        newton = None
        reuse = None
        if (
            guess is not None
            and guess.newton is not None
            and math.dist(guess.position_m, where) <= JACOBIAN_REUSE_M
        ):
            reuse = guess.newton
        for it in range(1, MAX_SAG_ITERATIONS + 1):
            if norm <= SAG_TOL:
                u = [
                    (horiz[i][0] * math.cos(a), horiz[i][1] * math.cos(a), math.sin(a))
                    for i, a in enumerate(theta)
                ]
                return self._solution(where, chords, ends, u, it, newton or reuse)
            if reuse is not None:
                newton, reuse = reuse, None
            else:
                try:
                    newton = self._newton_matrix(theta, t, ends, spans, rises, horiz)
                except SingularConfiguration:
                    break
            step = _gauss([list(row) for row in newton[0]], [-r for r in res])
            alpha = 1.0
            for _ in range(30):
                trial = [a + alpha * d for a, d in zip(theta, step, strict=True)]
                try:
                    t2, e2, r2 = self._pass(trial, spans, rises, horiz, where)
                except (SagError, SingularConfiguration):  # a step too far: shorter
                    alpha *= 0.5
                    continue
                n2 = max(abs(r) for r in r2)
                if n2 < norm or n2 <= SAG_TOL:
                    break
                alpha *= 0.5
            else:
                break
            theta, t, ends, res, norm = trial, t2, e2, r2, n2
        # Newton stalled: the planned distribution has a kink there (the cables that bind it
        # change), where the residuals have no derivative.  The fixed point "tangents ->
        # tensions -> tangents" needs none: it contracts, slowly, to the same solution.
        for it in range(FIXED_POINT_PASSES):
            theta = [a - r for a, r in zip(theta, res, strict=True)]
            try:
                t, ends, res = self._pass(theta, spans, rises, horiz, where)
            except (SagError, SingularConfiguration):
                break
            norm = max(abs(r) for r in res)
            if norm <= SAG_TOL:
                u = [
                    (horiz[i][0] * math.cos(a), horiz[i][1] * math.cos(a), math.sin(a))
                    for i, a in enumerate(theta)
                ]
                return self._solution(where, chords, ends, u, MAX_SAG_ITERATIONS + it, newton)
        # past the fold: a cable leaves the effector far below its chord
        below = [theta[i] - math.atan2(rises[i], spans[i]) for i in range(self.n)]
        low = min(range(self.n), key=lambda i: below[i])
        if below[low] < -0.5:
            raise SagError(
                f"cable {low + 1} would hang slack at {_fmt(where)}: its tangent at the effector "
                "turns downward as its tension falls, and no distribution of the tension rule "
                "pulls it taut against its weight"
            )
        raise SagError(
            f"the tensions with sag did not settle at {_fmt(where)} (tangents off by "
            f"{norm:.3g} rad)"
        )

    @staticmethod
    def _directions(
        theta: Sequence[float], spans: Sequence[float], horiz: Sequence[tuple[float, float]]
    ) -> list[Vec3]:
        """Unit pull directions of tangent elevations `theta` along the horizontal unit
        vectors `horiz` toward the anchors."""
        out = []
        for i, a in enumerate(theta):
            hx, hy = horiz[i]
            ca = math.cos(a)
            out.append(
                (hx * ca, hy * ca, math.sin(a))
                if spans[i] > 0.0
                else (0.0, 0.0, 1.0 if a > 0.0 else -1.0)
            )
        return out

    def _pass(
        self,
        theta: Sequence[float],
        spans: Sequence[float],
        rises: Sequence[float],
        horiz: Sequence[tuple[float, float]],
        where: Vec3,
    ) -> tuple[tuple[float, ...], list[catenary.CatenaryEnds], list[float]]:
        """The statics along the tangent elevations `theta`, each cable's catenary for its
        horizontal force, and how far each catenary's own tangent is from `theta` (rad):
        (tensions, ends, residuals).  Raises SagError for a cable that would hang slack."""
        t = _solve_along(self.statics, self._directions(theta, spans, horiz), self.weight_n)
        total = sum(t)
        if total - total != 0.0:
            raise SingularConfiguration("tensions overflow: the configuration is singular")
        ends = []
        res = []
        for i in range(self.n):
            ti = t[i]
            if not ti > 0.0:
                raise SagError(
                    f"cable {i + 1} would hang slack at ({where[0]:.4g}, {where[1]:.4g}, "
                    f"{where[2]:.4g}) m: the payload needs it to pull {ti:.4g} N"
                )
            a = theta[i]
            e = self._hang(i, spans[i], rises[i], ti * math.cos(a), ti * math.sin(a), where)
            ends.append(e)
            res.append(a - math.atan2(e.v0_n, e.h_n) if spans[i] > 0.0 else 0.0)
        return t, ends, res

    def _newton_matrix(
        self,
        theta: Sequence[float],
        t: Sequence[float],
        ends: Sequence[catenary.CatenaryEnds],
        spans: Sequence[float],
        rises: Sequence[float],
        horiz: Sequence[tuple[float, float]],
    ) -> Newton:
        """The Newton matrix of the residuals ``theta - theta'(theta)`` at `theta`: ``J = I -
        d theta' / d theta`` with the statics' tension derivative by the tangents by forward
        differences (one statics solve per cable) and the catenaries' tangent derivative by
        their horizontal force analytically; (J, dt/dtheta, d theta'/dH)."""
        n = self.n
        eps = 1e-7
        gp = [self._tangent_slopes(i, e, spans[i])[0] for i, e in enumerate(ends)]
        jac = [[0.0] * n for _ in range(n)]
        dtd = [[0.0] * n for _ in range(n)]
        cos_t = [math.cos(a) for a in theta]
        for j in range(n):
            bumped = list(theta)
            bumped[j] += eps
            tb = _solve_along(self.statics, self._directions(bumped, spans, horiz), self.weight_n)
            for i in range(n):
                dtd[i][j] = (tb[i] - t[i]) / eps
                # d H_i / d theta_j = cos(theta_i) dt_i/dtheta_j - [i = j] t_i sin(theta_i)
                dh = cos_t[i] * dtd[i][j]
                if i == j:
                    dh -= t[i] * math.sin(theta[i])
                jac[i][j] = (1.0 if i == j else 0.0) - gp[i] * dh
        return (
            tuple(tuple(row) for row in jac),
            tuple(tuple(row) for row in dtd),
            tuple(gp),
        )

    def _tangent_slopes(
        self, i: int, e: catenary.CatenaryEnds, span: float
    ) -> tuple[float, float, float, float, float, float]:
        """Cable `i`'s catenary `e` between fixed ends: how its tangent elevation at the
        effector and its unstretched length move (d theta'/dH; d theta'/d span, d theta'/d rise
        at fixed H; dL0/dH; dL0/d span, dL0/d rise at fixed H).  Zeros for a vertical one."""
        if not span > 0.0:
            return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        r = catenary.reach_derivatives(e.h_n, e.v0_n, e.unstretched_m, self._w[i], self._c[i])
        det = r.ds_dv * r.dr_dl - r.ds_dl * r.dr_dv
        if det == 0.0:
            return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        # (V0, L0) of the catenary with its ends: M [dV0, dL0] = [d span, d rise] - [ds_dh,
        # dr_dh] dH, M = [[ds_dv, ds_dl], [dr_dv, dr_dl]]
        dv_dh = (-r.dr_dl * r.ds_dh + r.ds_dl * r.dr_dh) / det
        dl_dh = (r.dr_dv * r.ds_dh - r.ds_dv * r.dr_dh) / det
        dv_ds, dv_dr = r.dr_dl / det, -r.ds_dl / det
        dl_ds, dl_dr = -r.dr_dv / det, r.ds_dv / det
        t2 = e.t0_n * e.t0_n
        return (
            (e.h_n * dv_dh - e.v0_n) / t2,
            e.h_n * dv_ds / t2,
            e.h_n * dv_dr / t2,
            dl_dh,
            dl_ds,
            dl_dr,
        )

    def _hang(
        self, i: int, span: float, rise: float, h: float, v: float, where: Vec3
    ) -> catenary.CatenaryEnds:
        """Cable `i`'s catenary for the horizontal force `h` (or, vertical, the vertical force
        `v`).  Raises SagError for a slack cable."""
        w, c = self._w[i], self._c[i]
        try:
            if span > 0.0:
                return catenary.from_horizontal_force(span, rise, h, w, c)
            if rise > 0.0:
                # straight up: rise = L0 (1 + c V0 + c w L0 / 2)
                b = 1.0 + c * v
                l0 = 2.0 * rise / (b + math.sqrt(b * b + 2.0 * c * w * rise))
            else:
                # straight down, pulled with -v: -rise = L0 (1 - c v - c w L0 / 2), its tension
                # falling by its weight toward the anchor
                b = 1.0 - c * v
                disc = b * b - 2.0 * c * w * -rise
                l0 = 2.0 * -rise / (b + math.sqrt(disc)) if disc > 0.0 else math.inf
                if not (-v - w * l0 > 0.0):
                    raise catenary.SlackCableError(
                        f"a cable straight down under the effector pulled with {-v:.4g} N "
                        "does not hold its own weight"
                    )
            return catenary.CatenaryEnds(0.0, v, v + w * l0, abs(v), abs(v + w * l0), l0, 0)
        except catenary.SlackCableError as exc:
            raise SagError(f"cable {i + 1} would hang slack at {_fmt(where)}: {exc}") from None
        except catenary.CatenaryError as exc:
            raise SagError(f"cable {i + 1} at {_fmt(where)}: {exc}") from None

    def _solution(
        self,
        p: Vec3,
        chords: list[float],
        ends: list[catenary.CatenaryEnds],
        u: list[Vec3],
        iterations: int,
        newton: Newton | None = None,
    ) -> SagSolution:
        lo, hi = self.statics.t_min_n, self.statics.t_max_n
        margin = math.inf
        limiting = 0
        bound: Literal["min", "max"] = "min"
        for i, e in enumerate(ends):
            d_lo = e.t0_n - lo
            d_hi = hi - e.t1_n
            if d_lo < margin:
                margin, limiting, bound = d_lo, i, "min"
            if d_hi < margin:
                margin, limiting, bound = d_hi, i, "max"
        paid = tuple(e.unstretched_m for e in ends)
        s = sum(paid) + margin
        if s - s != 0.0:
            raise SingularConfiguration("tensions overflow: the configuration is singular")
        return SagSolution(
            position_m=p,
            chords_m=tuple(chords),
            paid_out_m=paid,
            horizontal_n=tuple(e.h_n for e in ends),
            directions=tuple(u),
            effector_tensions_n=tuple(e.t0_n for e in ends),
            anchor_tensions_n=tuple(e.t1_n for e in ends),
            margin_n=margin,
            limiting_cable=limiting,
            limiting_bound=bound,
            iterations=iterations,
            newton=newton,
        )

    def from_horizontal(
        self, point_m: Sequence[float], horizontal_n: Sequence[float]
    ) -> SagSolution:
        """The cables at `point_m` pulling with the horizontal forces `horizontal_n`, each the
        catenary of its force between its ends (closed form and a Newton step or two for the
        stretch): their tangents, tensions and unstretched lengths, without the statics.  The
        end forces balance the weight when the forces are a solution's (``solve``), nearly so
        for forces linearised from one nearby.  Raises ``StaticsInputError`` for a bad point or
        count, ``SagError`` for a force that cannot hold its cable or a cable on its anchor's
        vertical."""
        if len(point_m) != 3 or len(horizontal_n) != self.n:
            raise StaticsInputError(
                f"need a point and {self.n} horizontal forces, got {len(point_m)} and "
                f"{len(horizontal_n)}"
            )
        px, py, pz = float(point_m[0]), float(point_m[1]), float(point_m[2])
        if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
            raise StaticsInputError(f"point_m ({px}, {py}, {pz}) is not finite")
        where = (px, py, pz)
        chords = []
        ends = []
        u = []
        for i, (ax, ay, az) in enumerate(self._anchors):
            dx, dy, dz = ax - px, ay - py, az - pz
            s = math.hypot(dx, dy)
            if not s > 0.0:
                raise SagError(f"cable {i + 1} is vertical at {_fmt(where)}")
            chords.append(math.sqrt(dx * dx + dy * dy + dz * dz))
            e = self._hang(i, s, dz, float(horizontal_n[i]), 0.0, where)
            ends.append(e)
            a = e.h_n / e.t0_n / s
            u.append((dx * a, dy * a, e.v0_n / e.t0_n))
        return self._solution(where, chords, ends, u, 0)

    def gradients(self, solution: SagSolution) -> tuple[tuple[Vec3, ...], tuple[Vec3, ...]]:
        """(dH / dP, d(chord - paid-out length) / dP) of each cable at `solution`'s pose (one
        row per cable; N/m and dimensionless): how the planned horizontal forces move with the
        pose, and the part of the paid-out lengths' derivative that sag and stretch add to the
        geometry's.

        By the implicit function theorem on the solve's residuals ``F(theta, P) = theta -
        theta'(theta, P) = 0``: ``J d theta / dP = d theta' / dP`` at fixed tangents, with the
        solve's Newton matrix J (taken afresh when the solve made none), the statics' tension
        change as the cables' bearings turn with P (two statics solves, forward differences)
        and each catenary's change with its span and rise (analytic).  Raises what ``solve``
        raises for a solution the statics no longer have."""
        n = self.n
        px, py, pz = solution.position_m
        spans, rises, horiz = [], [], []
        for ax, ay, az in self._anchors:
            dx, dy = ax - px, ay - py
            span = math.hypot(dx, dy)
            spans.append(span)
            rises.append(az - pz)
            horiz.append((dx / span, dy / span) if span > 0.0 else (0.0, 0.0))
        theta = [math.atan2(d[2], math.hypot(d[0], d[1])) for d in solution.directions]
        t = solution.effector_tensions_n
        ends = [
            catenary.CatenaryEnds(h, t0 * d[2], t0 * d[2] + w * l0, t0, t1, l0, 0)
            for h, t0, t1, d, w, l0 in zip(
                solution.horizontal_n,
                t,
                solution.anchor_tensions_n,
                solution.directions,
                self._w,
                solution.paid_out_m,
                strict=True,
            )
        ]
        newton = solution.newton or self._newton_matrix(theta, t, ends, spans, rises, horiz)
        jac, dtd, _ = newton
        # the statics' tensions as the bearings turn, at fixed tangent elevations
        eps = 1e-6
        dt_dp: list[list[float]] = [[0.0, 0.0, 0.0] for _ in range(n)]
        for k, (ex, ey) in enumerate(((eps, 0.0), (0.0, eps))):
            turned = []
            for ax, ay, _az in self._anchors:
                dx, dy = ax - px - ex, ay - py - ey
                span = math.hypot(dx, dy)
                turned.append((dx / span, dy / span) if span > 0.0 else (0.0, 0.0))
            tb = _solve_along(self.statics, self._directions(theta, spans, turned), self.weight_n)
            for i in range(n):
                dt_dp[i][k] = (tb[i] - t[i]) / eps
        slopes = [self._tangent_slopes(i, e, spans[i]) for i, e in enumerate(ends)]
        cos_t = [math.cos(a) for a in theta]
        sin_t = [math.sin(a) for a in theta]

        def span_rise(i: int, k: int) -> tuple[float, float]:
            """d span_i / dP_k, d rise_i / dP_k."""
            if k == 2:
                return 0.0, -1.0
            return -horiz[i][k], 0.0

        # d theta' / dP at fixed theta, one column per axis, solved for d theta / dP
        dtheta: list[list[float]] = []
        for k in range(3):
            rhs = []
            for i in range(n):
                gp, g_s, g_r = slopes[i][0], slopes[i][1], slopes[i][2]
                ds, dr = span_rise(i, k)
                rhs.append(gp * cos_t[i] * dt_dp[i][k] + g_s * ds + g_r * dr)
            dtheta.append(_gauss([list(row) for row in jac], rhs))
        dh_rows = []
        dd_rows = []
        for i in range(n):
            ax, ay, az = self._anchors[i]
            chord = solution.chords_m[i]
            dchord = ((px - ax) / chord, (py - ay) / chord, (pz - az) / chord)
            dl_dh, dl_ds, dl_dr = slopes[i][3], slopes[i][4], slopes[i][5]
            dh = []
            dd = []
            for k in range(3):
                dt_i = sum(dtd[i][j] * dtheta[k][j] for j in range(n)) + dt_dp[i][k]
                dhk = cos_t[i] * dt_i - t[i] * sin_t[i] * dtheta[k][i]
                ds, dr = span_rise(i, k)
                dh.append(dhk)
                dd.append(dchord[k] - (dl_dh * dhk + dl_ds * ds + dl_dr * dr))
            dh_rows.append((dh[0], dh[1], dh[2]))
            dd_rows.append((dd[0], dd[1], dd[2]))
        return tuple(dh_rows), tuple(dd_rows)


def _gauss(a: list[list[float]], b: list[float]) -> list[float]:
    """The solution of the small dense system a x = b (Gaussian elimination with partial
    pivoting; `a` and `b` are overwritten).  Raises SagError when it is singular."""
    n = len(b)
    for k in range(n):
        p = max(range(k, n), key=lambda r: abs(a[r][k]))
        if not abs(a[p][k]) > 1e-300:
            raise SagError("the tensions with sag are singular there")
        if p != k:
            a[k], a[p] = a[p], a[k]
            b[k], b[p] = b[p], b[k]
        piv = a[k][k]
        for r in range(k + 1, n):
            f = a[r][k] / piv
            if f != 0.0:
                row_r, row_k = a[r], a[k]
                for col in range(k, n):
                    row_r[col] -= f * row_k[col]
                b[r] -= f * b[k]
    x = [0.0] * n
    for k in range(n - 1, -1, -1):
        acc = b[k] - sum(a[k][col] * x[col] for col in range(k + 1, n))
        x[k] = acc / a[k][k]
    return x


def _fmt(p: Sequence[float]) -> str:
    return "(" + ", ".join(f"{float(v):.4g}" for v in p) + ") m"
