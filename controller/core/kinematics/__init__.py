"""Kinematics of a point-mass cable robot, after Williams & Needler, ASME IDETC 2014,
DETC2014-35185 (closed-form forward pose kinematics by the intersection of three spheres).

Pure package: ``math`` and ``numpy`` only, no I/O, no global state.  One module per concern:

* ``errors``: ``KinematicsError`` and its kinds.
* ``geometry``: ``Geometry`` (validated anchors, the seed triple, everything precomputed from
  the anchors alone), the plan-view footprint, IPK (``ipk_point`` per tick, ``ipk``
  vectorised); the conventions of the whole package.
* ``spheres``: the paper's three-spheres intersection, simplified (equal heights) and general,
  with their per-tick forms; the diagnosis of lengths that cannot meet.
* ``fitplan``: what the fit precomputes from the anchors (built by ``Geometry``).
* ``fitgen``: the among-anchors fit written out for one layout (built by ``Geometry``).
* ``fit``: ``fpk``, one pose over N cables: the three-spheres seed, then the least-squares fit.
* ``batch``: ``fpk_batch``, the same fit for many poses at once (offline analysis, benchmark).
"""

from controller.core.kinematics.batch import BATCH_CHUNK, FpkBatchResult, fpk_batch
from controller.core.kinematics.errors import (
    KinematicsError,
    SingularGeometryError,
    UnreachableError,
)
from controller.core.kinematics.fit import FpkResult, fpk
from controller.core.kinematics.geometry import (
    COINCIDENT_TOL_M,
    HEIGHT_TOL_M,
    SINGULAR_REL_TOL,
    Geometry,
    ipk,
    ipk_point,
    paper_anchors,
)
from controller.core.kinematics.spheres import (
    TANGENT_TOL_M,
    three_spheres,
    three_spheres_equal_height,
)

__all__ = [
    "BATCH_CHUNK",
    "COINCIDENT_TOL_M",
    "HEIGHT_TOL_M",
    "SINGULAR_REL_TOL",
    "TANGENT_TOL_M",
    "FpkBatchResult",
    "FpkResult",
    "Geometry",
    "KinematicsError",
    "SingularGeometryError",
    "UnreachableError",
    "fpk",
    "fpk_batch",
    "ipk",
    "ipk_point",
    "paper_anchors",
    "three_spheres",
    "three_spheres_equal_height",
]
