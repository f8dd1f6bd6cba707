"""Stage 3: correct samples onto the fibre with damped-least-squares (DLS) steps, in float64.

dq = J^T (J J^T + lambda^2 I)^-1 e, where e is the task error: the constrained
position axes, then the base-frame rotation vector log(R* R^T) (pose task) or the tool
axis's angle to its target as a 2-vector (axis task, `rotations.axis_error`). `iterate` is
the loop (rows that have converged take no further step), shared with the connect
stage's Newton projections (fibre.py); on a serial chain the same steps run whole in
compiled code (`native.newton`, the same kernels row by row: the same numbers bitwise).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from service.manifest import TaskSpec
from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.joint_space import JointLimits
from service.pipeline.native import AxisTarget
from service.pipeline.rotations import axis_error, normal_basis, rotation_error
from service.pipeline.targets import Target, kernel_orientation
from service.pipeline.types import (
    ChainKinematics,
    Correction,
    Kinematics,
    KinematicsResult,
    Tolerance,
    chain_of,
)


def dls_step(
    jacobian: FloatArray,  # (B, m, n)
    error: FloatArray,  # (B, m)
    damping: float,
) -> FloatArray:  # (B, n)
    """One damped-least-squares step dq = J^T (J J^T + damping^2 I)^-1 e per row (compiled:
    `native.dls_step`).

    Failures stay in their own rows: a row whose Jacobian or error is not finite gets a
    NaN step (its sample is then rejected), and a singular system (zero damping at a
    kinematic singularity) falls back to the pseudo-inverse instead of failing the batch.
    """
    return native.dls_step(jacobian, error, damping)


def task_error(
    fk: KinematicsResult, target: Target, task: TaskSpec
) -> tuple[FloatArray, FloatArray]:
    """Task error e (B, m) = target - current and the task Jacobian (B, m, n).

    The Jacobian's rows are the constrained position axes, then the orientation's: the
    angular rows (pose task; when those are all of the geometric Jacobian's rows in order,
    it is `fk.jacobian` itself, not a copy) or the axis task's two (`axis_error`).
    """
    axes = task.position_axes
    m_p = len(axes)
    orientation = kernel_orientation(task, target)
    if isinstance(orientation, AxisTarget):
        error_axis, jacobian_axis = axis_error(
            orientation.frame, fk.rotation, fk.jacobian[:, 3:, :]
        )  # (B, 2), (B, 2, n)
        position_error = target.position_m[None, :] - fk.position_m[:, axes]
        jacobian = np.concatenate([fk.jacobian[:, axes, :], jacobian_axis], axis=1)
        return np.concatenate([position_error, error_axis], axis=1), jacobian
    rows = [*axes, *([3, 4, 5] if orientation is not None else [])]
    jacobian = fk.jacobian if rows == list(range(6)) else fk.jacobian[:, rows, :]  # (B, m, n)
    error = np.empty((len(fk.position_m), len(rows)))  # (B, m)
    error[:, :m_p] = target.position_m[None, :] - fk.position_m[:, axes]
    if orientation is not None:
        error[:, m_p:] = rotation_error(orientation, fk.rotation)
    return error, jacobian


def jacobian_on_fibre(fk: KinematicsResult, task: TaskSpec) -> FloatArray:  # (B, m, n)
    """The task Jacobian of each configuration on its own fibre (the target it reaches):
    the position axes' rows, then the angular rows (pose) or (axis) the angular rows
    projected onto the plane normal to the tool axis, in an orthonormal basis of it. Its
    singular values are the task map's at those configurations."""
    axes = task.position_axes
    angular = fk.jacobian[:, 3:, :]  # (B, 3, n)
    if task.tool_axis is None:
        rows = [*axes, *([3, 4, 5] if task.orientation else [])]
        return fk.jacobian[:, rows, :]
    basis = normal_basis(fk.rotation @ np.asarray(task.tool_axis))  # (B, 2, 3)
    return np.concatenate([fk.jacobian[:, axes, :], basis @ angular], axis=1)


def task_error_norms(
    fk: KinematicsResult, target: Target, task: TaskSpec
) -> tuple[FloatArray, FloatArray]:
    """Position error (B,) in m and orientation error (B,) in rad (0 for a position task)."""
    return error_norms(task_error(fk, target, task)[0], task)


def error_norms(error: FloatArray, task: TaskSpec) -> tuple[FloatArray, FloatArray]:
    """|position part| (B,) in m and |orientation part| (B,) in rad of task errors (B, m):
    the rotation angle (pose) or the axis angle (axis)."""
    m_p = len(task.position_axes)
    position_error_m = np.linalg.norm(error[:, :m_p], axis=1)
    if not task.orientation_rows:
        return position_error_m, np.zeros(len(error))
    return position_error_m, np.linalg.norm(error[:, m_p:], axis=1)


# q (B, n) -> task error e (B, m) and Jacobian J (B, m, n).
Residual = Callable[[FloatArray], tuple[FloatArray, FloatArray]]


def residual_of(kinematics: Kinematics, target: Target, task: TaskSpec) -> Residual:
    """q -> (e, J) of `task_error`: in one compiled pass (`native.task_residual`) where the
    kinematics is a serial chain the kernels evaluate, else through the kinematics."""
    chain = chain_of(kinematics)
    if chain is not None:
        fixed, tip = chain.fixed, chain.tip
        axes, position = task.position_axes, target.position_m
        rotation = kernel_orientation(task, target)

        def compiled(q_rad: FloatArray) -> tuple[FloatArray, FloatArray]:
            return native.task_residual(fixed, tip, q_rad, axes, position, rotation)

        return compiled

    def through(q_rad: FloatArray) -> tuple[FloatArray, FloatArray]:
        return task_error(kinematics(q_rad), target, task)

    return through


def compiled_newton(
    chain: ChainKinematics,
    target: Target,
    task: TaskSpec,
    q_rad: FloatArray,  # (B, n) evaluated: error and jacobian are measured there
    error: FloatArray,  # (B, m)
    jacobian: FloatArray,  # (B, m, n)
    iterations: int,
    damping: float,
    until: float | None = None,
    locked: BoolArray | None = None,  # (B, n) or (n,) joints held fixed
    tangent: FloatArray | None = None,  # (B, n) bordered steps (r = 1)
    threads: int = 1,
    fresh: BoolArray | None = None,  # (B,) rows not yet evaluated (evaluated first)
) -> tuple[FloatArray, FloatArray, FloatArray]:  # q (B, n), error (B, m), jacobian (B, m, n)
    """`native.newton` on a serial chain's rows, the first part on the row helper with
    `threads` > 1 (rows.helper_rows): the same steps row by row, so the same numbers on any
    count."""
    rotation = kernel_orientation(task, target)
    return native.newton(
        chain.fixed, chain.tip, task.position_axes, target.position_m, rotation, q_rad, error,
        jacobian, iterations, damping, until, locked, tangent, fresh, threads,
    )  # fmt: skip


# J (A, m, n), e (A, m) of the rows still moving, and which rows they are (an index (A,),
# or slice(None) for every row, so per-row data is a view, not a copy) -> dq (A, n); a NaN
# row where there is no step.
StepRule = Callable[[FloatArray, FloatArray, IntArray | slice], FloatArray]

# A sample whose |e| is at most this takes no further DLS step. Newton converges
# quadratically here, so the step it skips would move it by about |e| (1e-12 rad or m),
# a millionth of the tolerance, and its answer is the same to that; on the iiwa14 pose at
# N = 1000 (10 steps) half the rows have stopped after 5 steps and 90 % after 8, which
# takes the stage from 13.7 to 10.8 ms.
CONVERGED_ERROR = 1e-12

# A correction that leaves no sample within the query's tolerance goes on before the
# answer says there is no solution: the samples within NEAR_TOLERANCES tolerances of the
# target take EXTRA_STEPS more DLS steps. Near a singular value of the task map (at the
# edge of the workspace: an arm stretched out) the damping slows DLS to a crawl: on the
# iiwa14 position model at its full reach, the served 10 steps left all 750 samples 1 to
# 4 um from the target (tolerance 1 um), 30 brought 733 of them within it and 100 all.
# A target that no sample comes that close to (out of reach) costs nothing more, and an
# answer with a sample within tolerance is the one the served steps give.
EXTRA_STEPS = 40
NEAR_TOLERANCES = 1000.0

# The compiled correction takes the rows in chunks of this many, with the deadline checked
# before each: about 4 ms of iiwa14 pose rows at 10 DLS steps.
CHUNK_ROWS = 2048


def iterate(
    q_rad: FloatArray,  # (B, n) configurations already evaluated
    error: FloatArray,  # (B, m) their task errors
    jacobian: FloatArray,  # (B, m, n) their Jacobians
    residual: Residual,
    step: StepRule,
    iterations: int,
    until: float | None = None,
    deadline: Deadline = NO_DEADLINE,
    stage: str = "correct",
) -> tuple[FloatArray, FloatArray, FloatArray]:  # q (B, n), e (B, m), J (B, m, n)
    """`iterations` steps q <- q + step(J, e), each evaluated: every returned
    configuration is one at which `residual` measured the returned error and Jacobian.

    With `until`, a row whose |e| is at most `until` takes no further step (a NaN row
    never stops; its NaN step makes it NaN), and each step is one `residual` call over
    the rows still moving; without, every row takes every step on whole arrays. A row
    whose step is not finite becomes NaN. `deadline` is checked before each step.
    """
    if until is None:  # every row takes every step: whole arrays, no row bookkeeping
        every = slice(None)
        for _ in range(iterations):
            deadline.check(stage)
            dq = step(jacobian, error, every)
            q_rad = np.where(np.isfinite(dq), q_rad + dq, np.nan)
            error, jacobian = residual(q_rad)
        return q_rad, error, jacobian
    q_rad, error, jacobian = q_rad.copy(), error.copy(), jacobian.copy()
    moving = np.flatnonzero(~(np.linalg.norm(error, axis=1) <= until))  # (A,)
    for _ in range(iterations):
        if not len(moving):
            break
        deadline.check(stage)
        dq = step(jacobian[moving], error[moving], moving)
        q_a = np.where(np.isfinite(dq), q_rad[moving] + dq, np.nan)
        error_a, jacobian_a = residual(q_a)
        q_rad[moving], error[moving], jacobian[moving] = q_a, error_a, jacobian_a
        moving = moving[~(np.linalg.norm(error_a, axis=1) <= until)]
    return q_rad, error, jacobian


def correct(
    q_rad: FloatArray,  # (N, n)
    target: Target,
    task: TaskSpec,
    kinematics: Kinematics,
    steps: int,
    damping: float,
    limits: JointLimits,  # its periodic joints come back wrapped
    deadline: Deadline = NO_DEADLINE,
    threads: int = 1,  # on a serial chain, the compiled steps' rows split over this many
) -> Correction:
    """Up to `steps` DLS steps on every finite sample (a sample stops once its |e| is at
    most CONVERGED_ERROR) and the remaining errors, measured where each sample ended.

    Samples with non-finite coordinates are left out of the arithmetic and get an
    infinite error, so acceptance rejects them without NaNs spreading; a sample that
    turns non-finite during the steps (a NaN from the kinematics) ends with a NaN error,
    which acceptance rejects too.
    """
    num_samples = q_rad.shape[0]
    finite = np.all(np.isfinite(q_rad), axis=1)  # (N,)
    position_error_m = np.full(num_samples, np.inf)
    orientation_error_rad = (
        np.where(finite, 0.0, np.inf) if task.orientation_rows else np.zeros(num_samples)
    )
    q_out = np.full_like(q_rad, np.nan)
    m = task.dimension
    jacobian_out = np.full((num_samples, m, q_rad.shape[1]), np.nan)
    if not finite.any():  # nothing to correct (and the kinematics needs a non-empty batch)
        return Correction(q_out, position_error_m, orientation_error_rad, jacobian_out)

    residual = residual_of(kinematics, target, task)
    q = q_rad[finite]
    chain = chain_of(kinematics)
    if chain is not None:  # every step of a chunk's rows compiled, the first evaluation too
        error, jacobian = np.empty((len(q), m)), np.empty((len(q), m, q.shape[1]))
        fresh = np.ones(len(q), dtype=bool)
        for first in range(0, len(q), CHUNK_ROWS):
            deadline.check("correct")
            rows = slice(first, first + CHUNK_ROWS)
            q[rows], error[rows], jacobian[rows] = compiled_newton(
                chain, target, task, q[rows], error[rows], jacobian[rows], steps,
                damping, until=CONVERGED_ERROR, threads=threads, fresh=fresh[rows],
            )  # fmt: skip
    else:

        def step(jacobian: FloatArray, error: FloatArray, rows: IntArray | slice) -> FloatArray:
            return dls_step(jacobian, error, damping)

        q, error, jacobian = iterate(
            q, *residual(q), residual, step, steps, until=CONVERGED_ERROR, deadline=deadline
        )
    position_error_m[finite], orientation_error_rad[finite] = error_norms(error, task)
    jacobian_out[finite] = jacobian
    q_out[finite] = limits.wrap(q)
    return Correction(
        q_rad=q_out,
        position_error_m=position_error_m,
        orientation_error_rad=orientation_error_rad,
        jacobian=jacobian_out,
    )


def correct_further(
    correction: Correction,
    tolerance: Tolerance,
    target: Target,
    task: TaskSpec,
    kinematics: Kinematics,
    damping: float,
    limits: JointLimits,
    deadline: Deadline = NO_DEADLINE,
    threads: int = 1,
) -> Correction:
    """`correction` itself when a sample is within `tolerance`; else the same with its
    samples within NEAR_TOLERANCES tolerances taken EXTRA_STEPS DLS steps further, from
    where they ended (the others as they were)."""
    position_error_m = correction.position_error_m
    orientation_error_rad = correction.orientation_error_rad
    if tolerance.within(position_error_m, orientation_error_rad).any():
        return correction
    near = Tolerance(
        NEAR_TOLERANCES * tolerance.position_m, NEAR_TOLERANCES * tolerance.orientation_rad
    )
    rows = np.flatnonzero(near.within(position_error_m, orientation_error_rad))  # (A,)
    if not len(rows):
        return correction
    further = correct(
        correction.q_rad[rows], target, task, kinematics, EXTRA_STEPS, damping, limits,
        deadline, threads,
    )  # fmt: skip
    q_rad, jacobian = correction.q_rad.copy(), correction.jacobian.copy()
    position_error_m, orientation_error_rad = position_error_m.copy(), orientation_error_rad.copy()
    q_rad[rows], jacobian[rows] = further.q_rad, further.jacobian
    position_error_m[rows] = further.position_error_m
    orientation_error_rad[rows] = further.orientation_error_rad
    return Correction(q_rad, position_error_m, orientation_error_rad, jacobian)
