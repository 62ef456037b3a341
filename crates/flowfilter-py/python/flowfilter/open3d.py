"""Open3D's registration API on Flow Filter's ICP: change one import line.

The names, signatures, defaults and result type of ``open3d.pipelines.registration`` for ICP::

    # from open3d.pipelines import registration as reg
    from flowfilter import open3d as reg

    result = reg.registration_icp(source, target, 0.02, np.identity(4),
                                  reg.TransformationEstimationPointToPlane(),
                                  reg.ICPConvergenceCriteria(max_iteration=50))
    print(result.fitness, result.inlier_rmse, result.transformation)

``source`` and ``target`` are ``open3d.geometry.PointCloud`` objects (points and normals used as
they are; Open3D need not be installed for anything else) or (N, 3) arrays. The estimation and
criteria objects may be this module's or Open3D's own. The poses are Open3D's (the Python
tests hold them to Open3D 0.20's on the peer fixtures); the time is Flow Filter's.

Raises ``flowfilter.InputError`` for clouds that cannot be used (point-to-plane without target
normals, an Open3D object that is not a point cloud) and ``flowfilter.ConfigError`` for what
Flow Filter's ICP does not do (robust kernels, scaling).
"""

from __future__ import annotations

import numpy as np

from ._flowfilter import ConfigError, InputError
from ._flowfilter import evaluate_registration as _evaluate
from ._flowfilter import register as _register

__all__ = [
    "ICPConvergenceCriteria",
    "RegistrationResult",
    "TransformationEstimationPointToPlane",
    "TransformationEstimationPointToPoint",
    "evaluate_registration",
    "registration_icp",
]


class ICPConvergenceCriteria:
    """Open3D's ICP stopping rule: relative change of fitness and of RMSE, and an iteration cap."""

    def __init__(self, relative_fitness: float = 1e-6, relative_rmse: float = 1e-6, max_iteration: int = 30):
        self.relative_fitness = float(relative_fitness)
        self.relative_rmse = float(relative_rmse)
        self.max_iteration = int(max_iteration)

    def __repr__(self) -> str:
        return (
            "ICPConvergenceCriteria class with relative_fitness={:e}, relative_rmse={:e}, and max_iteration={:d}"
        ).format(self.relative_fitness, self.relative_rmse, self.max_iteration)


class TransformationEstimationPointToPoint:
    """Point-to-point ICP (Flow Filter's ``icp-pt2pt``). ``with_scaling`` is not supported."""

    def __init__(self, with_scaling: bool = False):
        if with_scaling:
            raise ConfigError("TransformationEstimationPointToPoint: with_scaling=True is not supported (rigid only)")
        self.with_scaling = False

    def __repr__(self) -> str:
        return "TransformationEstimationPointToPoint with_scaling=False"


class TransformationEstimationPointToPlane:
    """Point-to-plane ICP (Flow Filter's ``icp-pt2pl``); needs the target's normals."""

    def __init__(self, kernel=None):
        if kernel is not None:
            raise ConfigError("TransformationEstimationPointToPlane: robust kernels are not supported (kernel=None)")
        self.kernel = None

    def __repr__(self) -> str:
        return "TransformationEstimationPointToPlane"


class RegistrationResult:
    """Open3D's ``RegistrationResult``: ``transformation``, ``fitness``, ``inlier_rmse``,
    ``correspondence_set``; plus ``converged``, ``iterations`` and ``seconds`` (Flow Filter's)."""

    def __init__(self, transformation, fitness, inlier_rmse, correspondence_set, converged=True, iterations=0, seconds=0.0):
        self.transformation = np.asarray(transformation, dtype=np.float64)
        self.fitness = float(fitness)
        self.inlier_rmse = float(inlier_rmse)
        self.correspondence_set = np.asarray(correspondence_set, dtype=np.int64).reshape(-1, 2)
        self.converged = bool(converged)
        self.iterations = int(iterations)
        self.seconds = float(seconds)

    def __repr__(self) -> str:
        return (
            "RegistrationResult with fitness={:e}, inlier_rmse={:e}, and correspondence_set size of {:d}\n"
            "Access transformation to get result."
        ).format(self.fitness, self.inlier_rmse, len(self.correspondence_set))


def _method(estimation_method) -> str:
    """The backend for an estimation object of this module or of Open3D (by class name)."""
    name = type(estimation_method).__name__
    if name == "TransformationEstimationPointToPoint":
        if getattr(estimation_method, "with_scaling", False):
            raise ConfigError("estimation_method: with_scaling=True is not supported (rigid only)")
        return "icp-pt2pt"
    if name == "TransformationEstimationPointToPlane":
        kernel = getattr(estimation_method, "kernel", None)
        if kernel is not None and type(kernel).__name__ != "L2Loss":
            raise ConfigError(f"estimation_method: robust kernel {type(kernel).__name__} is not supported")
        return "icp-pt2pl"
    raise ConfigError(
        "estimation_method: expected TransformationEstimationPointToPoint() or "
        f"TransformationEstimationPointToPlane(), found {name}"
    )


def _criteria(criteria) -> dict:
    """Open3D's criteria as the backend's parameters (its own or Open3D's object)."""
    try:
        return dict(
            max_iterations=int(criteria.max_iteration),
            relative_fitness=float(criteria.relative_fitness),
            relative_rmse=float(criteria.relative_rmse),
        )
    except AttributeError as e:
        raise ConfigError(f"criteria: expected ICPConvergenceCriteria, found {type(criteria).__name__}") from e


def _needs_normals(target) -> None:
    """An Open3D cloud without normals is refused here (arrays have none to give: the backend says so)."""
    has = getattr(target, "has_normals", None)
    if has is not None and not has():
        raise InputError(
            "target: point-to-plane ICP needs the target's normals (an open3d.geometry.PointCloud with normals, "
            "e.g. after target.estimate_normals())"
        )


def registration_icp(
    source,
    target,
    max_correspondence_distance: float,
    init=np.identity(4),
    estimation_method=TransformationEstimationPointToPoint(),
    criteria=ICPConvergenceCriteria(),
) -> RegistrationResult:
    """Open3D's ``registration_icp`` (same arguments, defaults and result) on Flow Filter's ICP."""
    method = _method(estimation_method)
    if method == "icp-pt2pl":
        _needs_normals(target)
    if not (np.isfinite(max_correspondence_distance) and max_correspondence_distance > 0):
        raise InputError(
            f"max_correspondence_distance: expected a positive distance (metres), found {max_correspondence_distance}"
        )
    r = _register(
        source,
        target,
        method=method,
        init=np.asarray(init, dtype=np.float64),
        max_correspondence_distance=float(max_correspondence_distance),
        min_update=0.0,
        **_criteria(criteria),
    )
    fitness, rmse, pairs = _evaluate(source, target, max_correspondence_distance, r.transformation)
    return RegistrationResult(r.transformation, fitness, rmse, pairs, r.converged, r.iterations, r.seconds)


def evaluate_registration(source, target, max_correspondence_distance: float, transformation=np.identity(4)) -> RegistrationResult:
    """Open3D's ``evaluate_registration``: fitness, inlier RMSE and correspondences of a given pose."""
    t = np.asarray(transformation, dtype=np.float64)
    fitness, rmse, pairs = _evaluate(source, target, max_correspondence_distance, t)
    return RegistrationResult(t, fitness, rmse, pairs)
