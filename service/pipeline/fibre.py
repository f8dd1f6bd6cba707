"""The fibre of a target, F = {q : FK(q) = x*}, as the connect stage walks on it.

Pure batched kernels around one primitive, the task residual e(q) = x* - FK(q) with its
Jacobian J(q) (B, m, n) (correction.task_error): Newton projection onto F (min-norm DLS
steps, float64), from fresh configurations or from ones already evaluated (no point is
evaluated twice), optionally keeping chosen joints fixed or moving orthogonally to a
tangent, each row stopping once within a given error; the unit tangent of a 1-D fibre;
the smallest singular value of J (per row, or the least over a batch; compiled), which
says how near the fibre is to a singular point (where components can touch).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from service.manifest import TaskSpec
from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.correction import Residual, compiled_newton, dls_step, iterate, residual_of
from service.pipeline.rows import over_rows
from service.pipeline.targets import Target
from service.pipeline.types import ChainKinematics, Kinematics, chain_of


@dataclass(frozen=True)
class Fibre:
    """The target's fibre: what projecting onto it needs."""

    target: Target
    task: TaskSpec
    kinematics: Kinematics
    damping: float  # DLS damping of the projection steps (the correction's)
    threads: int = 1  # the compiled Newton steps' rows split over this many (rows.py)

    def residual(self, q_rad: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Task error e (B, m) and task Jacobian J (B, m, n) at q_rad (B, n)."""
        return self._residual(q_rad)

    @cached_property
    def _residual(self) -> Residual:
        return residual_of(self.kinematics, self.target, self.task)

    @cached_property
    def chain(self) -> ChainKinematics | None:
        """The kinematics, where the compiled kernels evaluate it themselves."""
        return chain_of(self.kinematics)


@dataclass(frozen=True)
class Projection:
    """Configurations after Newton steps toward the fibre, with their measured errors."""

    q_rad: FloatArray  # (B, n) the last configurations evaluated
    error: FloatArray  # (B, m) task error at q_rad: position axes (m), then rotation (rad)
    jacobian: FloatArray  # (B, m, n) at q_rad

    @property
    def error_norm(self) -> FloatArray:  # (B,)
        return np.linalg.norm(self.error, axis=1)


def evaluate(fibre: Fibre, q_rad: FloatArray) -> Projection:  # q_rad (B, n)
    """The configurations as they are, with their measured error and Jacobian."""
    error, jacobian = fibre.residual(q_rad)
    return Projection(q_rad=q_rad, error=error, jacobian=jacobian)


def project(
    fibre: Fibre,
    q_rad: FloatArray,  # (B, n)
    iterations: int,
    locked: BoolArray | None = None,  # (B, n) joints held fixed
    tangent: FloatArray | None = None,  # (B, n) move orthogonally to this (1-D fibres)
    until: float | None = None,  # a row whose |e| is at most this takes no further step
) -> Projection:
    """`iterations` Newton steps onto the fibre; the returned points are all evaluated.

    Every returned configuration is one at which the kinematics was evaluated, so its
    error is measured, not extrapolated: iterations = k costs k + 1 evaluations (fewer
    for the rows that reach `until` early). With `locked`, the locked joints' columns of
    J are zeroed (those joints do not move); with `tangent` (r = 1 only) the step solves
    [J; t^T] dq = [e; 0], the corrector of pseudo-arclength continuation, which keeps the
    point from sliding along the fibre.
    """
    batch, n = q_rad.shape
    m = fibre.task.dimension
    unmeasured = Projection(q_rad.copy(), np.empty((batch, m)), np.empty((batch, m, n)))
    fresh = np.ones(batch, dtype=bool)
    return newton(fibre, unmeasured, iterations, locked, tangent, until, fresh)


def newton(
    fibre: Fibre,
    start: Projection,  # (B,) configurations already evaluated
    iterations: int,
    locked: BoolArray | None = None,  # (B, n)
    tangent: FloatArray | None = None,  # (B, n)
    until: float | None = None,
    fresh: BoolArray | None = None,  # (B,) rows of `start` not evaluated yet
) -> Projection:
    """`project` from configurations whose error and Jacobian are known: no evaluation is
    repeated, so iterations = k costs at most k evaluations per row; a `fresh` row is
    evaluated first (its given error and Jacobian are not read), in the same compiled
    call where the kinematics is a serial chain's.

    Each step is one batched kinematics call over the rows still moving: every row with
    `until` None, else the rows whose |e| is above `until` (or not finite). With a serial
    chain's kinematics, the steps of every row run compiled instead (`native.newton`,
    the same steps row by row, the rows split over `fibre.threads`; a DLS step needs
    damping above 0 there, which every manifest's is, since a singular system has no
    pseudo-inverse fallback in it).
    """
    kinematics = fibre.chain
    if kinematics is not None and (tangent is not None or fibre.damping > 0):
        q, error, jacobian = compiled_newton(
            kinematics, fibre.target, fibre.task, start.q_rad, start.error, start.jacobian,
            iterations, fibre.damping, until, locked, tangent, fibre.threads, fresh,
        )  # fmt: skip
        return Projection(q_rad=q, error=error, jacobian=jacobian)
    if fresh is not None and fresh.any():
        rows = np.flatnonzero(fresh)
        error, jacobian = start.error.copy(), start.jacobian.copy()
        error[rows], jacobian[rows] = fibre.residual(start.q_rad[rows])
        start = Projection(q_rad=start.q_rad, error=error, jacobian=jacobian)

    def step(jacobian: FloatArray, error: FloatArray, rows: IntArray | slice) -> FloatArray:
        return _step(
            fibre, jacobian, error,
            None if locked is None else locked[rows],
            None if tangent is None else tangent[rows],
        )  # fmt: skip

    q, error, jacobian = iterate(
        start.q_rad, start.error, start.jacobian, fibre.residual, step, iterations, until
    )
    return Projection(q_rad=q, error=error, jacobian=jacobian)


def _step(
    fibre: Fibre,
    jacobian: FloatArray,  # (B, m, n)
    error: FloatArray,  # (B, m)
    locked: BoolArray | None,  # (B, n)
    tangent: FloatArray | None,  # (B, n)
) -> FloatArray:  # (B, n) one Newton step; NaN rows where it has none
    if locked is not None:
        jacobian = np.where(locked[:, None, :], 0.0, jacobian)
    if tangent is None:
        return dls_step(jacobian, error, fibre.damping)
    return corrector_step(jacobian, error, tangent)


def corrector_step(
    jacobian: FloatArray,  # (B, n - 1, n)
    error: FloatArray,  # (B, n - 1)
    tangent: FloatArray,  # (B, n)
) -> FloatArray:  # (B, n)
    """dq with J dq = e and t . dq = 0; NaN rows where the system is singular (compiled:
    `native.bordered_solve`)."""
    batch, m, n = jacobian.shape
    rhs = np.zeros((batch, n))
    rhs[:, :m] = error
    return native.bordered_solve(jacobian, tangent, rhs)


def unit_tangent(
    jacobian: FloatArray,  # (B, n - 1, n)
    previous: FloatArray | None = None,  # (B, n) keeps the direction of travel
) -> FloatArray:  # (B, n) unit null vector of J; NaN rows where there is none
    """The unit tangent of a 1-D fibre: J t = 0, |t| = 1, and t . previous > 0.

    Without `previous`, the null vector is the last column of Q in J^T = QR (sign
    arbitrary; a third of an SVD's cost; NaN rows for a non-finite J); with it, from the
    bordered system [J; previous^T] t = [0; 1], which fixes the sign continuously (NaN
    rows where that system is singular).
    """
    batch, m, n = jacobian.shape
    if previous is None:
        finite = np.all(np.isfinite(jacobian), axis=(1, 2))
        tangent = np.full((batch, n), np.nan)
        if finite.any():
            q = np.linalg.qr(np.swapaxes(jacobian[finite], 1, 2), mode="complete")[0]
            tangent[finite] = q[:, :, -1]  # orthogonal to the rows of J
        return tangent
    rhs = np.zeros((batch, n))
    rhs[:, m] = 1.0
    direction = native.bordered_solve(jacobian, previous, rhs)  # (B, n)
    return direction / np.linalg.norm(direction, axis=1, keepdims=True)


def smallest_singular_value(jacobian: FloatArray) -> FloatArray:  # (B, m, n) -> (B,)
    """sigma_min of each task Jacobian: 0 at a singular configuration (NaN rows: NaN).
    Compiled for m <= n (`native.smallest_singular_values`, as accurate as LAPACK's SVD,
    which takes the other shapes)."""
    batch, m, n = jacobian.shape
    if 0 < m <= n:
        return native.smallest_singular_values(jacobian)
    finite = np.all(np.isfinite(jacobian), axis=(1, 2))
    sigma = np.full(batch, np.nan)
    if finite.any():
        sigma[finite] = np.linalg.svd(jacobian[finite], compute_uv=False)[:, -1]
    return sigma


def min_singular_value(jacobian: FloatArray, threads: int = 1) -> float:  # (B, m, n), m <= n
    """The least sigma_min over the rows with a finite J (inf for none): compiled, exact
    only for the rows whose cheap bound could hold the least (`native.least_singular_value`),
    the rows split over `threads` (the least of each chunk's least is the least)."""
    if 0 < jacobian.shape[1] <= jacobian.shape[2]:

        def least_of(rows: slice) -> float:
            return native.least_singular_value(jacobian[rows])

        return min(over_rows(least_of, len(jacobian), threads), default=np.inf)
    return float(np.nanmin(smallest_singular_value(jacobian), initial=np.inf))
