"""The tension-feasible workspace: where in a box the payload hangs with every cable tension
within its limits, sampled on a regular grid (`feasible_workspace`), with the volume and its
uncertainty. Built on `controller.core.statics.CableStatics`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from controller.core.statics import CableStatics, StaticsInputError, _finite

Margins = Callable[[NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.bool_]]]
"""Points (M, 3) -> (margin to the tension limits (M,), feasible (M,))."""


@dataclass(frozen=True, slots=True)
class FeasibleWorkspace:
    """Tension-feasible part of a box, sampled at cell centres on a regular grid.

    ``feasible[i, j, k]`` is the cell centred at ``(xs_m[i], ys_m[j], zs_m[k])``.
    ``volume_m3`` = ``n_feasible * cell_volume_m3``.  ``uncertainty_m3`` =
    ``n_boundary * cell_volume_m3``, where a boundary cell is one whose centre differs from a
    face neighbour's centre or, on the box's surface, from the centre of its outer face (sampled
    too): the limit surface crosses only such cells (at this resolution) and each can be
    misattributed by at most its volume, so this bounds the error of ``volume_m3``
    (conservatively: cells on both sides of the surface are counted) unless a feature smaller
    than a cell falls between samples.  Halving the step should change ``volume_m3`` by less.
    With a region (``inside``), a cell counts only when its centre is in the region too, the
    boundary is that of the intersection, and ``region_volume_m3`` is the region's sampled
    volume (``box_volume_m3`` without one).
    """

    xs_m: NDArray[np.float64]
    ys_m: NDArray[np.float64]
    zs_m: NDArray[np.float64]
    feasible: NDArray[np.bool_]
    margin_n: NDArray[np.float64]
    cell_m: tuple[float, float, float]
    cell_volume_m3: float
    box_volume_m3: float
    n_feasible: int
    n_boundary: int
    volume_m3: float
    uncertainty_m3: float
    n_region: int
    region_volume_m3: float


def _axis(rng: Sequence[float], step_m: float, name: str) -> tuple[NDArray[np.float64], float]:
    if len(rng) != 2:
        raise StaticsInputError(f"{name} must be (low, high), got {rng!r}")
    a, b = float(rng[0]), float(rng[1])
    if not (_finite(a) and _finite(b) and a < b):
        raise StaticsInputError(f"{name} must be finite with low < high, got {rng!r}")
    cells = max(1, round((b - a) / step_m))
    if cells > 100_000:
        raise StaticsInputError(f"{name}: step {step_m:g} m gives {cells} cells, too many")
    h = (b - a) / cells
    centres: NDArray[np.float64] = a + (np.arange(cells, dtype=np.float64) + 0.5) * h
    return centres, h


def feasible_workspace(
    anchors_m: ArrayLike,
    x_range_m: Sequence[float],
    y_range_m: Sequence[float],
    z_range_m: Sequence[float],
    step_m: float,
    mass_kg: float,
    t_min_n: float,
    t_max_n: float,
    inside: Callable[[NDArray[np.float64]], NDArray[np.bool_]] | None = None,
    margins: Margins | None = None,
) -> FeasibleWorkspace:
    """Sample the box on a regular grid and return where the tensions can stay in range.

    The box is cut into cells of about ``step_m`` (each axis into a whole number of equal
    cells, so the cells tile the box exactly; the actual sizes are ``cell_m``) and each cell
    centre is solved with ``tensions_batch`` (singular centres count as infeasible), and so is
    the centre of each outer face of the cells on the box's surface (for the uncertainty).
    ``inside``, given an (M, 3) array of points, says which lie in a region of interest (e.g.
    the geometric workspace, ``controller.core.workspace.Limits.inside_points``): only those
    count as feasible.  ``margins``, given an (M, 3) array of points, gives each point's
    (margin to the limits, feasible) in place of the straight cables' statics (the rule with
    the cables' weight, ``controller.core.sag_plan.SagTensionCheck.margins``).  Raises
    ``StaticsInputError`` for a bad box, step, mass or limits or more than 2e8 cells, and what
    ``tensions_batch`` raises.
    """
    try:
        step = float(step_m)
    except (TypeError, ValueError):
        raise StaticsInputError(f"step_m must be a number, got {step_m!r}") from None
    if not (_finite(step) and step > 0.0):
        raise StaticsInputError(f"step_m must be finite and > 0, got {step_m!r}")
    xs, hx = _axis(x_range_m, step, "x_range_m")
    ys, hy = _axis(y_range_m, step, "y_range_m")
    zs, hz = _axis(z_range_m, step, "z_range_m")
    shape = (xs.size, ys.size, zs.size)
    total = shape[0] * shape[1] * shape[2]
    if total > 200_000_000:
        raise StaticsInputError(f"{total} cells is too many; use a larger step")
    statics = CableStatics(anchors_m, t_min_n, t_max_n)
    if margins is None:

        def margins(points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
            _, m, ok, _ = statics.solve_batch(points, mass_kg)
            return m, ok

    gx, gy, gz = np.meshgrid(xs, ys, zs, indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel(), gz.ravel()], axis=1)
    margin, feasible = margins(pts)
    region = np.ones(total, dtype=bool) if inside is None else np.asarray(inside(pts), dtype=bool)
    feas = (feasible & region).reshape(shape)
    boundary = np.zeros(shape, dtype=bool)
    axes = (xs, ys, zs)
    # the box's faces: first and last centre -/+ half a cell
    bounds = tuple(
        (float(a[0]) - 0.5 * h, float(a[-1]) + 0.5 * h)
        for a, h in zip(axes, (hx, hy, hz), strict=True)
    )
    for ax in range(3):
        lo_sl: list[slice] = [slice(None)] * 3
        hi_sl: list[slice] = [slice(None)] * 3
        lo_sl[ax] = slice(None, -1)
        hi_sl[ax] = slice(1, None)
        diff = feas[tuple(lo_sl)] != feas[tuple(hi_sl)]
        boundary[tuple(lo_sl)] |= diff
        boundary[tuple(hi_sl)] |= diff
        # The outer half of a face cell has no neighbour: sample the box face itself there.
        for side, layer in ((0, 0), (1, shape[ax] - 1)):
            face_axes = [a if k != ax else np.array([bounds[ax][side]]) for k, a in enumerate(axes)]
            fx, fy, fz = np.meshgrid(*face_axes, indexing="ij")
            face_pts = np.stack([fx.ravel(), fy.ravel(), fz.ravel()], axis=1)
            face_ok = margins(face_pts)[1]
            if inside is not None:
                face_ok = face_ok & np.asarray(inside(face_pts), dtype=bool)
            face_ok = face_ok.reshape(fx.shape)
            sl: list[slice] = [slice(None)] * 3
            sl[ax] = slice(layer, layer + 1)
            boundary[tuple(sl)] |= feas[tuple(sl)] != face_ok
    cell = hx * hy * hz
    n_feasible = int(feas.sum())
    n_boundary = int(boundary.sum())
    for arr in (xs, ys, zs, feas):
        arr.setflags(write=False)
    mg = margin.reshape(shape)
    mg.setflags(write=False)
    box = (xs.size * hx) * (ys.size * hy) * (zs.size * hz)
    n_region = int(region.sum())
    return FeasibleWorkspace(
        xs_m=xs,
        ys_m=ys,
        zs_m=zs,
        feasible=feas,
        margin_n=mg,
        cell_m=(hx, hy, hz),
        cell_volume_m3=cell,
        box_volume_m3=box,
        n_feasible=n_feasible,
        n_boundary=n_boundary,
        volume_m3=n_feasible * cell,
        uncertainty_m3=n_boundary * cell,
        n_region=n_region,
        region_volume_m3=box if inside is None else n_region * cell,
    )
