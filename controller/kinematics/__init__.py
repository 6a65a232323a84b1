"""Kinematics of a point-mass cable robot (Williams & Needler, DETC2014-35185).

Pure package: ``math`` and ``numpy`` only, no I/O, no global state.
"""

from controller.kinematics.fit import (
    BATCH_CHUNK,
    COINCIDENT_TOL_M,
    HEIGHT_TOL_M,
    SINGULAR_REL_TOL,
    TANGENT_TOL_M,
    FpkBatchResult,
    FpkResult,
    Geometry,
    KinematicsError,
    SingularGeometryError,
    UnreachableError,
    footprint_contains,
    fpk,
    fpk_batch,
    ipk,
    ipk_point,
    paper_anchors,
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
    "footprint_contains",
    "fpk",
    "fpk_batch",
    "ipk",
    "ipk_point",
    "paper_anchors",
    "three_spheres",
    "three_spheres_equal_height",
]
