"""Kinematics with sag: the paid-out lengths for a set-point (IPK) and the pose of paid-out
lengths (FPK) with heavy, elastic cables, and the tension rule with their weight.

Pure module (``math``; the kinematics, statics and sag statics of this package), no I/O, no
threads.

* **Plans (IPK).** ``SagPlanner.plan`` gives the cables' end forces, tensions and paid-out
  lengths at a set-point.  A full solve (``SagStatics.solve``, a few hundred microseconds)
  is made at a *base* point with the gradients of the horizontal forces and of the paid-out
  lengths there; within ``PLAN_REUSE_M`` of the base a plan takes the horizontal forces
  linearised from it and each cable's catenary for its force in closed form (an elastic
  correction of a Newton step or two: ``SagStatics.from_horizontal``, about 30 us for four
  cables).  The linearisation's error grows with the square of the distance to the base:
  within 2.5 cm, under 0.1 mm of paid-out length on the paper robot with 3 mm steel rope and
  5 kg (``tests/core/test_sag.py``), far less with lighter cables; a move at 2 m/s and 500 Hz
  makes a new base every sixth tick.  Once the set-point is held, its plan is made exact
  (``refine``): the lengths the robot rests on carry no linearisation error.
* **FPK.** The paid-out lengths are the chords less what sag and stretch take up,
  ``L0_i(P) = |A_i - P| - d_i(P)``; ``d_i`` changes slowly with the pose, so it is linearised
  about a plan (the loop's set-point's, handed in, or one at the warm start) with the base's
  gradient, and the pose solved jointly from all cables by Gauss-Newton on
  ``|A_i - P| - d_i(P0) - g_i . (P - P0) = L0_i`` with the exact geometry (the least-squares
  solution: four cables over-determine the pose).  Warm-started from the last pose, two or
  three steps and no statics at all while the pose is within ``FPK_REUSE_M`` of the set-point;
  a pass that ends farther than ``RELINEARISE_M`` from its plan is repeated about its result.
* **The tension rule** (``SagTensionCheck``): ``TensionCheck`` with the sag statics:
  ``min_tension_n`` at the effector end of every cable, ``max_tension_n`` (or the motor's
  torque limit) at its anchor end.  Its ``solve`` is the loop's plan (so the check, the
  published tensions and the commanded lengths come from one solve); ``check`` and
  ``path_failure`` solve afresh and keep nothing (they also run in the threads that submit
  commands).

Errors: ``KinematicsError`` (``SagKinematicsError`` for what is specific to sag) for lengths no
pose explains; ``StaticsError`` (``SagError``) where the cables cannot hold the payload.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controller.core.kinematics import Geometry, KinematicsError, fpk
from controller.core.sag import SagSolution, SagStatics
from controller.core.statics import (
    PATH_MAX_SAMPLES,
    SINGULAR_MARGIN_N,
    StaticsError,
    TensionCheck,
    Tensions,
)
from controller.core.stretch import COLD_START_STRAINS, _normal_step

__all__ = [
    "CHECK_CACHE",
    "FPK_REUSE_M",
    "PLAN_REUSE_M",
    "RELINEARISE_M",
    "SAG_PATH_MAX_SAMPLES",
    "SagKinematicsError",
    "SagPlanner",
    "SagTensionCheck",
]

Vec3 = tuple[float, float, float]

PLAN_REUSE_M = 0.025
"""Plans within this distance of the last full solve are linearised from it."""
FPK_REUSE_M = 0.05
"""The FPK linearises about the plan handed in (the loop's set-point's) while the warm start
is within this distance of it (the effector lags a moving set-point by a few centimetres);
farther, about a full solve of its own at the warm start.  The linearisation's error grows with
the square of the distance: at 5 cm, up to 0.14 mm of pose on the paper robot with 3 mm steel
(near a corner low down), 0.1 mm close under the anchors, micrometres elsewhere
(``tests/core/test_sag.py``); at rest the pose is at the plan's point and the error nil."""
RELINEARISE_M = 0.05
"""A pass of the FPK about the set-point's plan that ends farther than this from it is
repeated about a solve of its own at its result."""
OWN_REUSE_M = 0.002
"""Without the set-point's plan near (disarmed), the FPK's own full solve and gradient are
reused while the warm start is within this distance of them."""
MAX_PASSES = 20
"""Most passes of one FPK."""
MAX_STEPS = 30
COLD_ROUNDS = 8
"""Most rounds of the cold start's "rigid FPK of the lengths plus the sag and stretch"."""
"""Most Gauss-Newton steps of one pass."""
STEP_TOL_M = 1e-8
"""A pass has converged when its step is shorter than this (the step is taken)."""
MAX_STEP_M = 0.5
"""Longest Gauss-Newton step: a longer one (a cold start far from the pose) ends the pass
there, and the next pass plans where it ended."""
COLD_PASSES = 40
"""Most passes of an FPK without a warm start."""
CHECK_CACHE = 8
"""Solutions ``SagTensionCheck.check`` keeps to linearise its later checks from."""
SAG_PATH_MAX_SAMPLES = 4000
"""At most this many solves per path check with sag (``SagTensionCheck.path_failure``): the
spacing grows to fit."""
_MATCH_M = 1e-9
"""Chords this close are the same set-point's (``SagPlanner.planned``)."""


class SagKinematicsError(KinematicsError):
    """The sag model cannot explain the lengths: no plan near the pose (the cables cannot hold
    the payload there), or the FPK did not converge."""


class SagPlanner:
    """Plans (IPK) and the FPK with sag for one robot (module docstring).

    Keeps the base solve, its gradients and the last few plans: one owner (the control loop's
    thread).  Raises nothing on construction.
    """

    __slots__ = (
        "_anchors",
        "_base",
        "_dd",
        "_dh",
        "_own",
        "_plans",
        "_plans_dd",
        "geometry",
        "n",
        "sag",
    )

    def __init__(self, sag: SagStatics, geometry: Geometry) -> None:
        self.sag = sag
        self.geometry = geometry
        self.n = sag.n
        self._anchors: tuple[Vec3, ...] = tuple(
            (float(a[0]), float(a[1]), float(a[2])) for a in geometry.anchors_m.tolist()
        )
        self._base: SagSolution | None = None
        self._dh: tuple[Vec3, ...] = ()
        self._dd: tuple[Vec3, ...] = ()
        self._plans: list[SagSolution] = []
        self._plans_dd: list[tuple[Vec3, ...]] = []
        self._own: tuple[SagSolution, tuple[Vec3, ...]] | None = None

    def reset(self) -> None:
        """Forget the base, the plans and the FPK's own solve: the next call solves afresh.
        Raises nothing."""
        self._base = None
        self._plans.clear()
        self._plans_dd.clear()
        self._own = None

    def exact(self, position_m: Sequence[float]) -> SagSolution:
        """A full solve at `position_m`, started from the base (keeps nothing).  Raises
        ``StaticsError`` (``SagError``) where the cables cannot hold the payload."""
        return self.sag.solve(position_m, self._base)

    def plan(self, position_m: Sequence[float]) -> SagSolution:
        """The cables' end forces, tensions and paid-out lengths at `position_m`: linearised
        from the base within ``PLAN_REUSE_M``, else a full solve there that becomes the base
        (with its gradients).  Kept for ``planned``.  Raises ``StaticsError`` (``SagError``,
        ``StaticsInputError``) where the cables cannot hold the payload or the point is bad."""
        p = (float(position_m[0]), float(position_m[1]), float(position_m[2]))
        base = self._base
        if base is not None and math.dist(base.position_m, p) <= PLAN_REUSE_M:
            bx, by, bz = base.position_m
            ex, ey, ez = p[0] - bx, p[1] - by, p[2] - bz
            h = [
                h0 + g[0] * ex + g[1] * ey + g[2] * ez
                for h0, g in zip(base.horizontal_n, self._dh, strict=True)
            ]
            sol = self.sag.from_horizontal(p, h)
        else:
            sol = self.sag.solve(p, base)
            self._dh, self._dd = self.sag.gradients(sol)
            self._base = sol
        self._keep(sol, self._dd)
        return sol

    def _keep(self, sol: SagSolution, dd: tuple[Vec3, ...]) -> None:
        self._plans.append(sol)
        self._plans_dd.append(dd)
        if len(self._plans) > 4:
            del self._plans[0]
            del self._plans_dd[0]

    def refine(self, chords_m: Sequence[float]) -> SagSolution | None:
        """The plan whose chords are `chords_m`, made exact: a linearised plan is replaced by
        a full solve at its point (the loop calls this when its set-point has stopped, so
        that the lengths it holds carry no linearisation error).  None when there is no such
        plan.  Raises ``StaticsError`` where the cables cannot hold the payload."""
        plan = self.planned(chords_m=chords_m)
        if plan is None or plan.iterations > 0:
            return plan
        sol = self.sag.solve(plan.position_m, plan)
        self._keep(sol, self.sag.gradients(sol)[1])
        return sol

    def planned(
        self, chords_m: Sequence[float] | None = None, position_m: Sequence[float] | None = None
    ) -> SagSolution | None:
        """The latest plan whose chords are `chords_m` (to a nanometre) or made at
        `position_m`, or None.  Raises nothing."""
        k = self._find(chords_m, position_m)
        return None if k is None else self._plans[k]

    def _find(
        self, chords_m: Sequence[float] | None, position_m: Sequence[float] | None
    ) -> int | None:
        for k in range(len(self._plans) - 1, -1, -1):
            s = self._plans[k]
            if position_m is not None and tuple(position_m) == s.position_m:
                return k
            if (
                chords_m is not None
                and len(chords_m) == self.n
                and all(abs(a - b) <= _MATCH_M for a, b in zip(chords_m, s.chords_m, strict=True))
            ):
                return k
        return None

    # ------------------------------------------------------------------ FPK

    def fpk(
        self,
        paid_m: Sequence[float],
        guess_m: Sequence[float] | None = None,
        planned_at: Sequence[float] | None = None,
    ) -> tuple[Vec3, float]:
        """(pose, RMS length mismatch in metres) of the paid-out lengths `paid_m` (module
        docstring), warm-started from `guess_m` (cold: the rigid FPK of the lengths), about
        the plan made at `planned_at` while the start is within ``FPK_REUSE_M`` of it.

        Raises ``KinematicsError`` for bad lengths or guess, ``SagKinematicsError`` when no
        plan can be made near the pose or a pass does not converge.
        """
        n = self.n
        if len(paid_m) != n:
            raise KinematicsError(f"need {n} cable lengths, got {len(paid_m)}")
        paid = [float(v) for v in paid_m]
        for i, v in enumerate(paid):
            if not (0.0 < v < math.inf):
                raise KinematicsError(f"cable {i + 1}: length must be finite and > 0, got {v!r}")
        if guess_m is None:
            p = self._cold_start(paid)
        else:
            p = (float(guess_m[0]), float(guess_m[1]), float(guess_m[2]))
            if not (math.isfinite(p[0]) and math.isfinite(p[1]) and math.isfinite(p[2])):
                raise KinematicsError(f"guess must be finite, got {tuple(guess_m)!r}")
        lin: tuple[SagSolution, tuple[Vec3, ...]] | None = None
        if planned_at is not None and math.dist(planned_at, p) <= FPK_REUSE_M:
            k = self._find(None, tuple(float(v) for v in planned_at))
            if k is not None:
                lin = self._plans[k], self._plans_dd[k]
        # about the set-point's plan, the pose may end RELINEARISE_M from it; about the FPK's
        # own solves (which cost it a full solve), OWN_REUSE_M
        reach = RELINEARISE_M
        prev_move = math.inf
        best: tuple[float, Vec3] | None = None
        for k in range(MAX_PASSES if guess_m is not None else COLD_PASSES):
            if lin is None:
                lin = self._solve_near(p)
                reach = OWN_REUSE_M
            if k > 0:  # a pass's start, linearised at itself: its exact mismatch
                d0 = [c - v for c, v in zip(lin[0].chords_m, lin[0].paid_out_m, strict=True)]
                ss_p = self._sum_squares(p, lin[0], lin[1], d0, paid)
                if best is None or ss_p < best[0]:
                    best = (ss_p, p)
            q, ss, capped = self._pass(p, lin[0], lin[1], paid)
            move = math.dist(lin[0].position_m, q)
            if capped:  # far from the pose: on toward it, a plan where the pass stopped
                prev_move = math.inf
            elif move <= reach:
                return q, math.sqrt(ss / n)
            elif move >= prev_move:  # not contracting (a kink of the distribution): half way
                q = (0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1]), 0.5 * (p[2] + q[2]))
                prev_move = math.dist(p, q)
            else:
                prev_move = move
            p = q
            lin = None
        # The passes did not settle: the planned distribution has a kink there (the cable that
        # limits it changes) and the lengths disagree with it, so the passes step across the
        # kink.  The best pose seen, by its exact mismatch.
        if best is None:
            raise SagKinematicsError(f"the FPK with sag did not settle at {_fmt(p)}")
        return best[1], math.sqrt(best[0] / n)

    def _cold_start(self, paid: list[float]) -> Vec3:
        """A first pose without a last one: the rigid FPK of the paid-out lengths (or where
        those cannot meet, cables stretched close under the anchors, of the lengths stretched
        by a growing guess of the strain, ``stretch.COLD_START_STRAINS``), then a few rounds
        of the rigid FPK of the paid-out lengths plus what sag and stretch take up at the last
        estimate (while the cables can hold the payload there)."""
        for strain in COLD_START_STRAINS:
            try:
                g = fpk(self.geometry, [v * (1.0 + strain) for v in paid]).position_m
            except KinematicsError:
                if strain == COLD_START_STRAINS[-1]:
                    raise
                continue
            break
        p = (float(g[0]), float(g[1]), float(g[2]))
        last = None
        for _ in range(COLD_ROUNDS):
            try:
                last = self.sag.solve(p, last)
                taken = [c - v for c, v in zip(last.chords_m, last.paid_out_m, strict=True)]
                g = fpk(self.geometry, [v + d for v, d in zip(paid, taken, strict=True)]).position_m
            except (StaticsError, KinematicsError):
                break
            q = (float(g[0]), float(g[1]), float(g[2]))
            moved = math.dist(p, q)
            p = q
            if moved < OWN_REUSE_M:
                break
        return p

    def _solve_near(self, p: Vec3) -> tuple[SagSolution, tuple[Vec3, ...]]:
        """The FPK's own linearisation near `p`: a full solve with its gradient, kept and
        reused while within ``OWN_REUSE_M``.  Raises SagKinematicsError where the cables
        cannot hold the payload."""
        own = self._own
        if own is not None and math.dist(own[0].position_m, p) <= OWN_REUSE_M:
            return own
        try:
            sol = self.sag.solve(p, own[0] if own is not None else self._base)
            grad = self.sag.gradients(sol)[1]
        except StaticsError as exc:
            raise SagKinematicsError(f"no cable tensions with sag at {_fmt(p)}: {exc}") from None
        self._own = (sol, grad)
        return sol, grad

    def _pass(
        self, start: Vec3, lin: SagSolution, grad: Sequence[Vec3], paid: Sequence[float]
    ) -> tuple[Vec3, float, bool]:
        """Gauss-Newton from `start` with the sag and stretch linearised about the plan `lin`
        with the gradient `grad`: (pose, sum of squared length mismatches, whether the pass
        stopped at a step of ``MAX_STEP_M``, far from the pose).  Raises SagKinematicsError
        without convergence."""
        x0, y0, z0 = lin.position_m
        d0 = [ch - l0 for ch, l0 in zip(lin.chords_m, lin.paid_out_m, strict=True)]
        anchors = self._anchors
        x, y, z = start
        for _ in range(MAX_STEPS):
            ex, ey, ez = x - x0, y - y0, z - z0
            a11 = a12 = a13 = a22 = a23 = a33 = 0.0
            b1 = b2 = b3 = 0.0
            ss = 0.0
            for i, (ax, ay, az) in enumerate(anchors):
                dx, dy, dz = ax - x, ay - y, az - z
                length = math.sqrt(dx * dx + dy * dy + dz * dz)
                gx, gy, gz = grad[i]
                ri = length - d0[i] - gx * ex - gy * ey - gz * ez - paid[i]
                inv = 1.0 / length
                j1, j2, j3 = -dx * inv - gx, -dy * inv - gy, -dz * inv - gz
                a11 += j1 * j1
                a12 += j1 * j2
                a13 += j1 * j3
                a22 += j2 * j2
                a23 += j2 * j3
                a33 += j3 * j3
                b1 -= j1 * ri
                b2 -= j2 * ri
                b3 -= j3 * ri
                ss += ri * ri
            step = _normal_step(a11, a12, a13, a22, a23, a33, b1, b2, b3)
            if step is None:
                raise SagKinematicsError(f"the cables do not fix the pose at {_fmt((x, y, z))}")
            sx, sy, sz = step
            size = math.sqrt(sx * sx + sy * sy + sz * sz)
            if size > MAX_STEP_M:  # far from the plan: no longer than the model holds
                f = MAX_STEP_M / size
                sx, sy, sz = sx * f, sy * f, sz * f
            x, y, z = x + sx, y + sy, z + sz
            if size <= STEP_TOL_M:
                return (x, y, z), self._sum_squares((x, y, z), lin, grad, d0, paid), False
            if size > MAX_STEP_M:
                # a new plan where the model is out of its range: end the pass here
                return (x, y, z), self._sum_squares((x, y, z), lin, grad, d0, paid), True
        raise SagKinematicsError(
            f"the FPK with sag did not converge in {MAX_STEPS} steps (at {_fmt((x, y, z))})"
        )

    def _sum_squares(
        self,
        p: Vec3,
        lin: SagSolution,
        grad: Sequence[Vec3],
        d0: Sequence[float],
        paid: Sequence[float],
    ) -> float:
        x0, y0, z0 = lin.position_m
        ex, ey, ez = p[0] - x0, p[1] - y0, p[2] - z0
        ss = 0.0
        for i, (ax, ay, az) in enumerate(self._anchors):
            length = math.sqrt((ax - p[0]) ** 2 + (ay - p[1]) ** 2 + (az - p[2]) ** 2)
            gx, gy, gz = grad[i]
            r = length - d0[i] - gx * ex - gy * ey - gz * ez - paid[i]
            ss += r * r
        return ss


class SagTensionCheck(TensionCheck):
    """The tension rule with the cables' weight: `TensionCheck`'s interface, each pose solved
    with sag (module docstring).  ``planner`` makes the loop's plans.

    ``solve`` returns a `Tensions` with the anchor-end tensions (what the reels carry) and the
    margin of the `SagSolution` (``min`` at the effector end, ``max`` at the anchor end); it
    carries no derivative.  Raises ``StaticsInputError`` as `TensionCheck` and `SagStatics`
    do.
    """

    __slots__ = ("_near", "planner", "sag")

    def __init__(
        self,
        anchors_m: ArrayLike,
        mass_kg: float,
        t_min_n: float,
        t_max_n: float,
        margin_n: float,
        max_source: str,
        weight_n_per_m: Sequence[float],
        ea_n: Sequence[float | None],
    ) -> None:
        super().__init__(anchors_m, mass_kg, t_min_n, t_max_n, margin_n, max_source)
        self.sag = SagStatics(self.statics, self.mass_kg, weight_n_per_m, ea_n)
        self.planner = SagPlanner(self.sag, Geometry(self.statics.anchors_m))
        self._near: list[tuple[SagSolution, tuple[Vec3, ...]]] = []

    def tensions(self, s: SagSolution) -> Tensions:
        """The `Tensions` of a sag solution (anchor-end tensions; its margin).  Raises
        nothing."""
        return Tensions(
            tensions_n=s.anchor_tensions_n,
            feasible=s.margin_n >= 0.0,
            margin_n=s.margin_n,
            limiting_cable=s.limiting_cable,
            limiting_bound=s.limiting_bound,
            t_min_n=self.statics.t_min_n,
            t_max_n=self.statics.t_max_n,
            method="sag",
        )

    def solve(self, point_m: Sequence[float], derivative: bool = False) -> Tensions:
        """The payload's tensions at P with sag: the planner's plan there (`derivative` is
        ignored: the plan's gradients come with its base).  Raises what ``SagPlanner.plan``
        raises."""
        return self.tensions(self.planner.plan(point_m))

    def reason(self, result: Tensions) -> str | None:
        """None if `result` passes, else why: the cable (1-based), the end and the bound."""
        if result.margin_n >= self.margin_n:
            return None
        i = result.limiting_cable
        lo, hi, m = self.statics.t_min_n, self.statics.t_max_n, self.margin_n
        if result.limiting_bound == "min":
            return (
                f"cable {i + 1} tension {lo + result.margin_n:.4g} N at the effector below "
                f"{lo + m:.4g} N (min_tension_n {lo:g} N + tension_margin_n {m:g} N) holding "
                f"{self.mass_kg:g} kg and the cables' weight"
            )
        return (
            f"cable {i + 1} tension {hi - result.margin_n:.4g} N at the anchor above "
            f"{hi - m:.4g} N ({self.max_source} {hi:.4g} N - tension_margin_n {m:g} N) holding "
            f"{self.mass_kg:g} kg and the cables' weight"
        )

    def check(self, point_m: Sequence[float]) -> str | None:
        """None if the payload can be held at P by the rule with sag, else the reason.

        The loop checks targets and, in velocity mode, points along the braking distance every
        tick (``CHECK_CACHE`` of them): within ``PLAN_REUSE_M`` of a solution this check made
        before, the horizontal forces are linearised from it and the catenaries solved in
        closed form (tensions to about 0.1 N, against a margin of newtons); farther, a full
        solve with its gradient, kept.  The cache is a hint any thread may share: its list
        operations are atomic and its entries immutable.  Raises nothing."""
        try:
            p = (float(point_m[0]), float(point_m[1]), float(point_m[2]))
            near = None
            best = PLAN_REUSE_M
            cache = list(self._near)
            for entry in cache:
                d = math.dist(entry[0].position_m, p)
                if d <= best:
                    near, best = entry, d
            if near is not None:
                sol, dh = near
                bx, by, bz = sol.position_m
                ex, ey, ez = p[0] - bx, p[1] - by, p[2] - bz
                h = [
                    h0 + g[0] * ex + g[1] * ey + g[2] * ez
                    for h0, g in zip(sol.horizontal_n, dh, strict=True)
                ]
                found = self.sag.from_horizontal(p, h)
            else:
                guess = (
                    min(cache, key=lambda e: math.dist(e[0].position_m, p))[0] if cache else None
                )
                found = self.sag.solve(p, guess)
                self._near.append((found, self.sag.gradients(found)[0]))
                if len(self._near) > CHECK_CACHE:
                    self._near.pop(0)
            return self.reason(self.tensions(found))
        except (StaticsError, IndexError, ValueError) as exc:
            return f"the cables cannot hold {self.mass_kg:g} kg there: {exc}"

    def margins(
        self, points_m: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """(margin to the limits shrunk by the margin, feasible) of each of M points (M, 3)
        with sag, each solve started from the point before (a grid's neighbour); a point the
        cables cannot hold is infeasible with margin ``SINGULAR_MARGIN_N``.  The
        ``controller.core.feasible`` map of this rule.  Raises nothing for finite points."""
        pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
        margin = np.full(pts.shape[0], SINGULAR_MARGIN_N)
        ok = np.zeros(pts.shape[0], dtype=bool)
        last: SagSolution | None = None
        for k, row in enumerate(pts.tolist()):
            if last is not None and math.dist(last.position_m, row) > 1.0:
                last = None  # a far neighbour's tangents are no better than the chords
            try:
                last = self.sag.solve(row, last)
            except StaticsError:
                last = None
                continue
            margin[k] = last.margin_n - self.margin_n
            ok[k] = margin[k] >= 0.0
        return margin, ok

    def path_failure(
        self,
        points: Sequence[Sequence[float]],
        start_m: Sequence[float] | None,
        step_m: float,
        max_samples: int = PATH_MAX_SAMPLES,
    ) -> tuple[int, str] | None:
        """`TensionCheck.path_failure` with sag: the legs sampled every `step_m` (coarser to
        keep within ``SAG_PATH_MAX_SAMPLES`` solves), each solve started from the sample
        before; keeps nothing.  Raises nothing for finite points."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if start_m is None:
            starts = np.vstack([pts[:1], pts[:-1]])
        else:
            starts = np.vstack([np.asarray(start_m, dtype=np.float64).reshape(1, 3), pts[:-1]])
        leg = pts - starts
        length = np.sqrt(np.einsum("ij,ij->i", leg, leg))
        counts = np.maximum(1, np.ceil(length / step_m)).astype(np.int64)
        cap = min(max_samples, SAG_PATH_MAX_SAMPLES)
        total = int(counts.sum())
        if total > cap:
            counts = np.maximum(1, np.ceil(counts * (cap / total))).astype(np.int64)
        last: SagSolution | None = None
        for i in range(len(pts)):
            k = int(counts[i])
            for j in range(1, k + 1):
                f = j / k
                q = starts[i] + f * leg[i]
                point = (float(q[0]), float(q[1]), float(q[2]))
                try:
                    last = self.sag.solve(point, last)
                    why = self.reason(self.tensions(last))
                except StaticsError as exc:
                    last = None
                    why = f"the cables cannot hold {self.mass_kg:g} kg there: {exc}"
                if why is not None:
                    if f < 1.0:
                        at = "[" + ", ".join(f"{v:.4f}" for v in point) + "]"
                        return i, f"on the leg to it: at {at}: {why}"
                    return i, why
        return None


def _fmt(p: Sequence[float]) -> str:
    return "(" + ", ".join(f"{float(v):.4g}" for v in p) + ") m"
