"""The fibre of a target, F = {q : FK(q) = x*}, as the connect stage walks on it.

Pure batched kernels around one primitive, the task residual e(q) = x* - FK(q) with its
Jacobian J(q) (B, m, n) (correction.task_error): Newton projection onto F (min-norm DLS
steps, float64), optionally keeping chosen joints fixed or moving orthogonally to a
tangent; the unit tangent of a 1-D fibre; the smallest singular value of J, which says
how near the fibre is to a singular point (where components can touch).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np

from service.manifest import TaskSpec
from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.correction import dls_step, task_error
from service.pipeline.targets import Target
from service.pipeline.types import Kinematics


@dataclass(frozen=True)
class Fibre:
    """The target's fibre: what projecting onto it needs."""

    target: Target
    task: TaskSpec
    kinematics: Kinematics
    damping: float  # DLS damping of the projection steps (the correction's)

    def residual(self, q_rad: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Task error e (B, m) and task Jacobian J (B, m, n) at q_rad (B, n)."""
        return task_error(self.kinematics(q_rad), self.target, self.task)


@dataclass(frozen=True)
class Projection:
    """Configurations after Newton steps toward the fibre, with their measured errors."""

    q_rad: FloatArray  # (B, n) the last configurations evaluated
    error: FloatArray  # (B, m) task error at q_rad: position axes (m), then rotation (rad)
    jacobian: FloatArray  # (B, m, n) at q_rad

    @property
    def error_norm(self) -> FloatArray:  # (B,)
        return np.linalg.norm(self.error, axis=1)


def project(
    fibre: Fibre,
    q_rad: FloatArray,  # (B, n)
    iterations: int,
    locked: BoolArray | None = None,  # (B, n) joints held fixed
    tangent: FloatArray | None = None,  # (B, n) move orthogonally to this (1-D fibres)
) -> Projection:
    """`iterations` Newton steps onto the fibre; the returned points are all evaluated.

    Every returned configuration is one at which the kinematics was evaluated, so its
    error is measured, not extrapolated: iterations = k costs k + 1 evaluations. With
    `locked`, the locked joints' columns of J are zeroed (those joints do not move); with
    `tangent` (r = 1 only) the step solves [J; t^T] dq = [e; 0], the corrector of
    pseudo-arclength continuation, which keeps the point from sliding along the fibre.
    """
    q = q_rad.copy()
    error, jacobian = fibre.residual(q)  # (B, m), (B, m, n)
    for _ in range(iterations):
        if locked is not None:
            jacobian = np.where(locked[:, None, :], 0.0, jacobian)
        if tangent is None:
            dq = dls_step(jacobian, error, fibre.damping)
        else:
            dq = corrector_step(jacobian, error, tangent)
        q = np.where(np.isfinite(dq), q + dq, np.nan)
        error, jacobian = fibre.residual(q)
    return Projection(q_rad=q, error=error, jacobian=jacobian)


def corrector_step(
    jacobian: FloatArray,  # (B, n - 1, n)
    error: FloatArray,  # (B, n - 1)
    tangent: FloatArray,  # (B, n)
) -> FloatArray:  # (B, n)
    """dq with J dq = e and t . dq = 0; NaN rows where the system is singular."""
    batch, _, _n = jacobian.shape
    system = np.concatenate([jacobian, tangent[:, None, :]], axis=1)  # (B, n, n)
    rhs = np.concatenate([error, np.zeros((batch, 1))], axis=1)[..., None]  # (B, n, 1)
    return _solve_rows(system, rhs)[..., 0]


def unit_tangent(
    jacobian: FloatArray,  # (B, n - 1, n)
    previous: FloatArray | None = None,  # (B, n) keeps the direction of travel
) -> FloatArray:  # (B, n) unit null vector of J; NaN rows where J is rank-deficient
    """The unit tangent of a 1-D fibre: J t = 0, |t| = 1, and t . previous > 0.

    Without `previous`, the null vector comes from an SVD (sign arbitrary); with it, from
    the bordered system [J; previous^T] t = [0; 1], which fixes the sign continuously.
    """
    batch, m, n = jacobian.shape
    if previous is None:
        finite = np.all(np.isfinite(jacobian), axis=(1, 2))
        tangent = np.full((batch, n), np.nan)
        if finite.any():
            tangent[finite] = np.linalg.svd(jacobian[finite])[2][:, -1, :]
        return tangent
    system = np.concatenate([jacobian, previous[:, None, :]], axis=1)  # (B, n, n)
    rhs = np.zeros((batch, n, 1))
    rhs[:, m, 0] = 1.0
    direction = _solve_rows(system, rhs)[..., 0]  # (B, n)
    return direction / np.linalg.norm(direction, axis=1, keepdims=True)


def smallest_singular_value(jacobian: FloatArray) -> FloatArray:  # (B, m, n) -> (B,)
    """sigma_min of each task Jacobian: 0 at a singular configuration (NaN rows: NaN)."""
    finite = np.all(np.isfinite(jacobian), axis=(1, 2))
    sigma = np.full(len(jacobian), np.nan)
    if finite.any():
        sigma[finite] = np.linalg.svd(jacobian[finite], compute_uv=False)[:, -1]
    return sigma


def _solve_rows(system: FloatArray, rhs: FloatArray) -> FloatArray:
    """Batched solve that leaves a NaN row for each singular or non-finite system."""
    out = np.full(rhs.shape, np.nan)
    finite = np.all(np.isfinite(system), axis=(1, 2)) & np.all(np.isfinite(rhs), axis=(1, 2))
    if not finite.any():
        return out
    try:
        out[finite] = np.linalg.solve(system[finite], rhs[finite])
    except np.linalg.LinAlgError:
        for row in np.flatnonzero(finite):
            with contextlib.suppress(np.linalg.LinAlgError):
                out[row] = np.linalg.solve(system[row], rhs[row])
    return out
