"""Compiled kernels for the pipeline's innermost loops: kinematics, Newton steps, the walks, GJK.

Why compiled: every stage after sampling calls these on a few dozen rows at a time (the
trace's fronts, the Newton projections), hundreds of times per answer, where numpy
spends its time in the overhead of tens of small array calls, not in arithmetic. Per
row they are a few hundred floating-point operations, which compiled code does in well
under a microsecond.

Why C: the kernels are small, fixed-size linear algebra over one row at a time, which
C99 says plainly; the extension (native.c) builds with the C compiler and the headers
that every CPython build comes with, at install time (`pip install .`, the README's
commands, the Dockerfile's build stage), with no numpy headers (arrays arrive through the
buffer protocol) and no run-time dependency. It writes nothing at run time, so the
service keeps running on a read-only root file system, and it starts with the process:
no JIT. numba was weighed: its LLVM (llvmlite, 173 MB installed) would have taken the
image from about 500 to 700 MB, compiles at start-up unless its cache is written
beforehand, and its cache locator requires a writable directory.

Each wrapper checks what the C code relies on (float64, C-contiguous, shapes) and
allocates the outputs; the C code loops over rows with the GIL released. Each kernel is
pinned by tests/service/pipeline/test_native.py to the numpy implementation it replaces
(1e-12) and to pytorch-kinematics; the trace's refinement near the limits, cut by the
limits and dense layout, by tests/service/pipeline/connect/test_densify.py to the Python
loops they replaced (to the bit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.pipeline import _native  # type: ignore[attr-defined]
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.rows import helper_rows

# The C code keeps a chain's joint frames on the stack.
MAX_JOINTS = 64
# The self-clearance kernels count each body's placed spheres on the stack.
MAX_BODIES = 64
# The DLS step's system is m x m on the stack: at most a full pose.
MAX_TASK_DIMENSION = 6


def _float64(array: FloatArray, name: str, shape: tuple[int, ...]) -> FloatArray:
    """`array` as C-contiguous float64 of `shape` (a copy only where it is not already)."""
    out = np.ascontiguousarray(array, dtype=np.float64)
    if out.shape != shape:
        raise ValueError(f"{name} has shape {out.shape}; expected {shape}")
    return out


def chain_kinematics(
    fixed: FloatArray,  # (n, 4, 4) joint i's fixed transform, its axis turned onto z
    tip: FloatArray,  # (4, 4) from the last joint's frame to the end effector
    q_rad: FloatArray,  # (B, n)
) -> tuple[FloatArray, FloatArray, FloatArray]:  # position (B, 3), rotation (B, 3, 3), J (B, 6, n)
    """Forward kinematics and geometric Jacobian of a serial chain of revolute joints.

    Joint i's frame is the previous one times fixed[i] times Rz(q_i); the end effector is
    the last frame times `tip`. The Jacobian is in the base frame, linear rows first:
    z_i x (p_ee - p_i), then z_i. A non-finite joint value gives non-finite outputs in
    its own row only.
    """
    n = len(fixed)
    if not 0 < n <= MAX_JOINTS:
        raise ValueError(f"a chain of {n} joints; the kernel takes 1 to {MAX_JOINTS}")
    fixed = _float64(fixed, "fixed", (n, 4, 4))
    tip = _float64(tip, "tip", (4, 4))
    batch = len(q_rad)
    q = _float64(q_rad, "q_rad", (batch, n))
    position = np.empty((batch, 3))
    rotation = np.empty((batch, 3, 3))
    jacobian = np.empty((batch, 6, n))
    if batch:
        _native.chain(fixed, tip, q, n, batch, position, rotation, jacobian)
    return position, rotation, jacobian


def rotation_error(
    rotation_target: FloatArray,  # (3, 3)
    rotation: FloatArray,  # (B, 3, 3)
) -> FloatArray:  # (B, 3)
    """Base-frame rotation vector e with exp([e]) R = R*, that is log(R* R^T), per row.

    Below 150 degrees it is read off the skew part of R* R^T; beyond, off its quaternion
    (the largest of trace and diagonal chooses the formula, as scipy's does). A row that
    is no rotation (non-finite, or R* R^T with a non-positive determinant) gets NaN.
    """
    target = _float64(rotation_target, "rotation_target", (3, 3))
    batch = len(rotation)
    rotations = _float64(rotation, "rotation", (batch, 3, 3))
    error = np.empty((batch, 3))
    if batch:
        _native.rotation_error(target, rotations, batch, error)
    return error


def dls_step(
    jacobian: FloatArray,  # (B, m, n)
    error: FloatArray,  # (B, m)
    damping: float,
) -> FloatArray:  # (B, n)
    """dq = J^T (J J^T + damping^2 I)^-1 e per row, by LU with partial pivoting.

    A row whose Jacobian or error is not finite gets a NaN step. A row whose system is
    exactly singular (zero damping at a kinematic singularity) takes the pseudo-inverse's
    step instead.
    """
    batch, m, n = np.shape(jacobian)
    if not 0 < m <= MAX_TASK_DIMENSION:
        raise ValueError(f"a task of dimension {m}; the kernel takes 1 to {MAX_TASK_DIMENSION}")
    j = _float64(jacobian, "jacobian", (batch, m, n))
    e = _float64(error, "error", (batch, m))
    step = np.empty((batch, n))
    singular = np.zeros(batch, dtype=np.uint8)
    if batch:
        _native.dls_step(j, e, batch, m, n, float(damping), step, singular)
    if singular.any():
        rows = singular.astype(bool)
        gram = j[rows] @ np.swapaxes(j[rows], 1, 2)
        gram.reshape(len(gram), m * m)[:, :: m + 1] += damping * damping
        step[rows] = (np.swapaxes(j[rows], 1, 2) @ (np.linalg.pinv(gram) @ e[rows][..., None]))[
            ..., 0
        ]
    return step


def chain_frames(
    origin: FloatArray,  # (n, 4, 4) each joint's fixed transform from the previous frame
    axis: FloatArray,  # (n, 3) each joint's unit axis
    q_rad: FloatArray,  # (B, n)
) -> FloatArray:  # (B, n + 1, 4, 4)
    """T_0 = I and T_k = T_{k-1} origin_k Rot(axis_k, q_k), Rot by Rodrigues' formula: the
    URDF frame of every joint's child link, base frame, metres."""
    n = len(origin)
    origin = _float64(origin, "origin", (n, 4, 4))
    axis = _float64(axis, "axis", (n, 3))
    batch = len(q_rad)
    q = _float64(q_rad, "q_rad", (batch, n))
    frames = np.empty((batch, n + 1, 4, 4))
    if batch:
        _native.frames(origin, axis, q, n, batch, frames)
    return frames


def _int64(array: IntArray, name: str, shape: tuple[int, ...]) -> IntArray:
    out = np.ascontiguousarray(array, dtype=np.int64)
    if out.shape != shape:
        raise ValueError(f"{name} has shape {out.shape}; expected {shape}")
    return out


def self_clearance_m(
    rotation: FloatArray,  # (B, K, 3, 3) each body's frame
    origin_m: FloatArray,  # (B, K, 3)
    centre_local_m: FloatArray,  # (K, S, 3) each body's spheres in its frame
    radius_m: FloatArray,  # (K, S)
    own_spheres: IntArray,  # (K,) the first own_spheres[k] spheres of body k are its own
    bound_local_m: FloatArray,  # (K, 3) each body's bounding sphere
    bound_radius_m: FloatArray,  # (K,)
    pair_a: IntArray,  # (P,) the checked body pairs
    pair_b: IntArray,  # (P,)
) -> FloatArray:  # (B,)
    """The least |c_a - c_b| - r_a - r_b over the sphere pairs of the checked body pairs
    (negative: overlapping), +inf with no pair; NaN where a frame is not finite. Body
    pairs whose bounding spheres are no nearer than the least gap found so far are
    skipped: they cannot lower it."""
    batch, count = len(rotation), len(centre_local_m)
    bodies = _Bodies.of(centre_local_m, radius_m, own_spheres, bound_local_m, bound_radius_m,
                        pair_a, pair_b)  # fmt: skip
    rotation = _float64(rotation, "rotation", (batch, count, 3, 3))
    origin = _float64(origin_m, "origin_m", (batch, count, 3))
    clearance = np.empty(batch)
    scratch = np.empty(count * bodies.spheres * 3 + count * 3 + 1)
    if batch:
        arguments = (rotation, origin, batch, count, *bodies.arguments, clearance, scratch)
        _native.self_clearance(*arguments)
    return clearance


def self_clearance_at_m(
    joint_origin: FloatArray,  # (n, 4, 4) as `chain_frames`
    joint_axis: FloatArray,  # (n, 3)
    q_rad: FloatArray,  # (B, n)
    frame: IntArray,  # (K,) the chain frame (0 to n) each body moves with
    centre_local_m: FloatArray,  # (K, S, 3), and the rest as `self_clearance_m`
    radius_m: FloatArray,  # (K, S)
    own_spheres: IntArray,  # (K,)
    bound_local_m: FloatArray,  # (K, 3)
    bound_radius_m: FloatArray,  # (K,)
    pair_a: IntArray,  # (P,)
    pair_b: IntArray,  # (P,)
    threads: int = 1,
) -> FloatArray:  # (B,)
    """`self_clearance_m` with each body in chain frame frame[k] at q_rad (`chain_frames`),
    row by row: the same numbers, without storing every frame of every row. With `threads`
    > 1 and enough rows (`helper_rows`) the first part runs on the row helper."""
    n, batch, count = len(joint_origin), len(q_rad), len(centre_local_m)
    bodies = _Bodies.of(centre_local_m, radius_m, own_spheres, bound_local_m, bound_radius_m,
                        pair_a, pair_b)  # fmt: skip
    frames = _int64(frame, "frame", (count,))
    if count and (frames.min() < 0 or frames.max() > n):
        raise ValueError(f"body frames must lie in 0 to {n}")
    clearance = np.empty(batch)
    first = helper_rows(batch, threads)
    per_thread = (n + 1) * 16 + count * 12 + count * bodies.spheres * 3 + count * 3 + 1
    scratch = np.empty(per_thread * (2 if first else 1))
    if batch:
        _native.self_clearance_at(
            _float64(joint_origin, "joint_origin", (n, 4, 4)),
            _float64(joint_axis, "joint_axis", (n, 3)), n,
            _float64(q_rad, "q_rad", (batch, n)), batch, frames, count,
            *bodies.arguments, clearance, scratch, first,
        )  # fmt: skip
    return clearance


def hull_separation_m(
    hulls_local_m: FloatArray,  # (H, V, 3) every hull's vertices in its frame, padded
    counts: IntArray,  # (H,) each hull's own vertex count (at least 1)
    hull_a: IntArray,  # (N,) each pair's first hull
    rotation_a: FloatArray,  # (N, 3, 3) its frame -> base frame
    origin_a_m: FloatArray,  # (N, 3)
    hull_b: IntArray,  # (N,) each pair's second hull
    rotation_b: FloatArray,  # (N, 3, 3)
    origin_b_m: FloatArray,  # (N, 3)
    x0_m: FloatArray,  # (N, 3) a point of A - B to start from
    pad_m: FloatArray,  # (N,) pad_A + pad_B
    margin_m: float,
    measure: IntArray,  # (M,) the pairs to measure
) -> FloatArray:  # (N,)
    """`collision.convex.separation_m` between placed hulls, each row's GJK whole in
    compiled code: the best lower bound of the distance between A + ball(pad_A) and
    B + ball(pad_B) at the rows measured, -inf at the others."""
    num_hulls, width = len(hulls_local_m), hulls_local_m.shape[1]
    count = _int64(counts, "counts", (num_hulls,))
    if num_hulls and (count.min() < 1 or count.max() > width):
        raise ValueError(f"hull vertex counts must lie in 1 to {width}")
    batch = len(x0_m)
    a, b = _int64(hull_a, "hull_a", (batch,)), _int64(hull_b, "hull_b", (batch,))
    rows = _int64(measure, "measure", (len(measure),))
    for name, index, size in (("hull_a", a, num_hulls), ("hull_b", b, num_hulls),
                              ("measure", rows, batch)):  # fmt: skip
        if len(index) and (index.min() < 0 or index.max() >= size):
            raise ValueError(f"{name} must index 0 to {size - 1}")
    best = np.full(batch, -np.inf)
    if len(rows):
        _native.hull_separation(
            _float64(hulls_local_m, "hulls_local_m", (num_hulls, width, 3)), count, width,
            a, _float64(rotation_a, "rotation_a", (batch, 3, 3)),
            _float64(origin_a_m, "origin_a_m", (batch, 3)),
            b, _float64(rotation_b, "rotation_b", (batch, 3, 3)),
            _float64(origin_b_m, "origin_b_m", (batch, 3)),
            _float64(x0_m, "x0_m", (batch, 3)), _float64(pad_m, "pad_m", (batch,)),
            float(margin_m), rows, len(rows), best,
        )  # fmt: skip
    return best


# The obstacle shapes in the order of native.c's OBSTACLE_* codes (scene.py's SHAPES).
OBSTACLE_SHAPES = ("box", "sphere", "cylinder", "capsule")


@dataclass(frozen=True)
class ObstacleSet:
    """A request's obstacles as the compiled obstacle passes take them (scene.py's Scene)."""

    shape: IntArray  # (O,) each one's index in OBSTACLE_SHAPES
    dims_m: FloatArray  # (O, 3) its dimensions (scene.py's DIMENSION_NAMES), unused ones 0
    rotation: FloatArray  # (O, 3, 3) obstacle frame -> base frame
    position_m: FloatArray  # (O, 3)
    reach_m: FloatArray  # (O,) the radius about its position that holds it
    pad_m: FloatArray  # (O,) the radius its core is grown by

    @classmethod
    def empty(cls) -> ObstacleSet:
        return cls(
            shape=np.zeros(0, dtype=np.int64), dims_m=np.zeros((0, 3)),
            rotation=np.zeros((0, 3, 3)), position_m=np.zeros((0, 3)), reach_m=np.zeros(0),
            pad_m=np.zeros(0),
        )  # fmt: skip

    def arguments(self) -> tuple[object, ...]:
        count = len(self.shape)
        shape = _int64(self.shape, "shape", (count,))
        if count and (shape.min() < 0 or shape.max() >= len(OBSTACLE_SHAPES)):
            raise ValueError(f"obstacle shapes must index {list(OBSTACLE_SHAPES)}")
        return (
            shape, _float64(self.dims_m, "dims_m", (count, 3)),
            _float64(self.rotation, "rotation", (count, 3, 3)),
            _float64(self.position_m, "position_m", (count, 3)),
            _float64(self.reach_m, "reach_m", (count,)), _float64(self.pad_m, "pad_m", (count,)),
            count,
        )  # fmt: skip


@dataclass(frozen=True)
class MovingBodies:
    """The robot's bodies as the compiled obstacle passes take them (robot.py's
    RobotSpheres): K bodies of S spheres padded, each sphere's hull of V vertices padded,
    and which of them move (obstacles are checked against those only)."""

    centre_local_m: FloatArray  # (K, S, 3) in each body's frame
    radius_m: FloatArray  # (K, S)
    own_spheres: IntArray  # (K,) the first own_spheres[k] of body k are its own
    bound_local_m: FloatArray  # (K, 3) each body's bounding sphere
    bound_radius_m: FloatArray  # (K,)
    moving: IntArray  # (M,) the bodies that move
    hull_local_m: FloatArray  # (K, S, V, 3)
    hull_count: IntArray  # (K, S) each hull's own vertices (at least 1)
    hull_pad_m: FloatArray  # (K, S)

    def arguments(self) -> tuple[object, ...]:
        k, s = self.radius_m.shape
        v = self.hull_local_m.shape[2]
        moving = _int64(self.moving, "moving", (len(self.moving),))
        if len(moving) and (moving.min() < 0 or moving.max() >= k):
            raise ValueError(f"moving must index bodies 0 to {k - 1}")
        counts = _int64(self.hull_count, "hull_count", (k, s))
        if counts.size and (counts.min() < 1 or counts.max() > v):
            raise ValueError(f"hull vertex counts must lie in 1 to {v}")
        own = _int64(self.own_spheres, "own_spheres", (k,))
        if own.size and (own.min() < 1 or own.max() > s):
            raise ValueError(f"own sphere counts must lie in 1 to {s}")
        return (
            _float64(self.centre_local_m, "centre_local_m", (k, s, 3)),
            _float64(self.radius_m, "radius_m", (k, s)), own,
            _float64(self.bound_local_m, "bound_local_m", (k, 3)),
            _float64(self.bound_radius_m, "bound_radius_m", (k,)), moving,
            _float64(self.hull_local_m, "hull_local_m", (k, s, v, 3)), counts,
            _float64(self.hull_pad_m, "hull_pad_m", (k, s)), k, s, len(moving), v,
        )  # fmt: skip


def _obstacle_pass(
    bodies: MovingBodies,
    obstacles: ObstacleSet,
    rotation: FloatArray,
    origin_m: FloatArray,
    refined: bool,
    margin_m: float,
    within_m: FloatArray,
) -> FloatArray:
    body_arguments, obstacle_arguments = bodies.arguments(), obstacles.arguments()
    (k, s), m, count = bodies.radius_m.shape, len(bodies.moving), len(obstacles.shape)
    batch = len(rotation)
    rotation = _float64(rotation, "rotation", (batch, k, 3, 3))
    origin = _float64(origin_m, "origin_m", (batch, k, 3))
    within = _float64(within_m, "within_m", (batch,))
    clearance = np.empty(batch)
    scratch = np.empty(m * max(count + 6, s + 4) + 1)
    if batch:
        _native.obstacle_clearance(
            *body_arguments, *obstacle_arguments, rotation, origin, batch, refined,
            float(margin_m), within, clearance, scratch,
        )  # fmt: skip
    return clearance


def obstacle_clearance_m(
    bodies: MovingBodies,
    obstacles: ObstacleSet,
    rotation: FloatArray,  # (B, K, 3, 3) each body's frame at B configurations
    origin_m: FloatArray,  # (B, K, 3)
    within_m: FloatArray,  # (B,) the least clearance found so far (+inf: none)
) -> FloatArray:  # (B,)
    """scene.py's `Scene.clearance_m`, row by row in compiled code: the least of `within_m`
    and the signed distance (negative: penetrating) of the moving bodies' spheres to any
    obstacle; NaN where a frame is not finite."""
    return _obstacle_pass(bodies, obstacles, rotation, origin_m, False, 0.0, within_m)


def refined_obstacle_clearance_m(
    bodies: MovingBodies,
    obstacles: ObstacleSet,
    rotation: FloatArray,  # (R, K, 3, 3) each body's frame at R configurations
    origin_m: FloatArray,  # (R, K, 3)
    margin_m: float,
) -> FloatArray:  # (R,)
    """scene.py's `Scene.refined_clearance_m`, row by row in compiled code: a lower bound
    of the moving bodies' least distance to the obstacles, the hulls' GJK separation
    (the steps of convex.py's separation_m) where the spheres are under the margin."""
    rows = len(rotation)
    return _obstacle_pass(
        bodies, obstacles, rotation, origin_m, True, margin_m, np.full(rows, np.inf)
    )


@dataclass(frozen=True)
class _Bodies:
    """The robot's spheres as the self-clearance kernels take them, checked."""

    spheres: int
    arguments: tuple[object, ...]  # S, centre, radius, own, bound, bound_radius, a, b, P

    @classmethod
    def of(
        cls,
        centre_local_m: FloatArray,
        radius_m: FloatArray,
        own_spheres: IntArray,
        bound_local_m: FloatArray,
        bound_radius_m: FloatArray,
        pair_a: IntArray,
        pair_b: IntArray,
    ) -> _Bodies:
        count, spheres = len(centre_local_m), centre_local_m.shape[1]
        pairs = len(pair_a)
        if count > MAX_BODIES:
            raise ValueError(f"{count} bodies; the kernels take at most {MAX_BODIES}")
        if count and (own_spheres.min() < 1 or own_spheres.max() > spheres):
            raise ValueError(f"own_spheres must lie in 1 to {spheres}")
        a, b = _int64(pair_a, "pair_a", (pairs,)), _int64(pair_b, "pair_b", (pairs,))
        if pairs and (min(a.min(), b.min()) < 0 or max(a.max(), b.max()) >= count):
            raise ValueError(f"body pairs must index 0 to {count - 1}")
        return cls(
            spheres=spheres,
            arguments=(
                spheres,
                _float64(centre_local_m, "centre_local_m", (count, spheres, 3)),
                _float64(radius_m, "radius_m", (count, spheres)),
                _int64(own_spheres, "own_spheres", (count,)),
                _float64(bound_local_m, "bound_local_m", (count, 3)),
                _float64(bound_radius_m, "bound_radius_m", (count,)),
                a, b, pairs,
            ),
        )  # fmt: skip


def bordered_solve(
    jacobian: FloatArray,  # (B, n - 1, n)
    border: FloatArray,  # (B, n)
    rhs: FloatArray,  # (B, n)
) -> FloatArray:  # (B, n)
    """x with [J; border^T] x = rhs per row, by LU with partial pivoting (LAPACK gesv's
    pivots): the corrector and tangent systems of a 1-D fibre. NaN rows where the system
    is not finite or exactly singular."""
    batch, m, n = np.shape(jacobian)
    if m != n - 1 or not 0 < n <= MAX_JOINTS:
        raise ValueError(f"a ({m}, {n}) Jacobian; the kernel takes (n - 1, n), n 1 to {MAX_JOINTS}")
    j = _float64(jacobian, "jacobian", (batch, m, n))
    t = _float64(border, "border", (batch, n))
    b = _float64(rhs, "rhs", (batch, n))
    x = np.empty((batch, n))
    if batch:
        _native.bordered_solve(j, t, b, batch, n, x, np.empty(n * n))
    return x


@dataclass(frozen=True)
class AxisTarget:
    """The axis task's orientation target as the kernels take it: `rotations.axis_frame`'s
    rows b1, b2 (spanning the plane normal to the target axis) and u (the tool axis in
    the end-effector frame); its 2 task rows are `rotations.axis_error`'s."""

    frame: FloatArray  # (3, 3)


# The orientation part of a target as the kernels take it: R* (3, 3) for a pose, an
# AxisTarget for the axis task, None for a position task.
OrientationTarget = FloatArray | AxisTarget | None


def _orientation(target: OrientationTarget) -> tuple[list[int], FloatArray]:
    """The geometric Jacobian's rows the orientation part reads (the angular ones: 3 for a
    pose, the 2 rows' count for an axis) and the (3, 3) matrix the kernel is given."""
    if target is None:
        return [], np.eye(3)
    if isinstance(target, AxisTarget):
        return [3, 4], _float64(target.frame, "axis frame", (3, 3))
    return [3, 4, 5], _float64(target, "target_rotation", (3, 3))


def task_residual(
    fixed: FloatArray,  # (n, 4, 4) as `chain_kinematics`
    tip: FloatArray,  # (4, 4)
    q_rad: FloatArray,  # (B, n)
    position_axes: list[int],  # the constrained base-frame axes of the position
    target_position_m: FloatArray,  # (len(position_axes),)
    target_rotation: OrientationTarget,  # R* (3, 3), an AxisTarget, or None (position)
) -> tuple[FloatArray, FloatArray]:  # error (B, m), jacobian (B, m, n)
    """The task error e = target - current (the position axes, then log(R* R^T) for a
    pose or `rotations.axis_error` for an axis) and the task Jacobian (those rows of the
    geometric one, or the axis rows made from the angular ones) in one pass: what
    `correction.task_error` makes of `chain_kinematics`, without the intermediate arrays."""
    n = len(fixed)
    if not 0 < n <= MAX_JOINTS:
        raise ValueError(f"a chain of {n} joints; the kernel takes 1 to {MAX_JOINTS}")
    orientation_rows, rotation = _orientation(target_rotation)
    rows = [*position_axes, *orientation_rows]
    m, m_position = len(rows), len(position_axes)
    if not 0 < m <= MAX_TASK_DIMENSION or not set(position_axes) <= {0, 1, 2}:
        raise ValueError(f"position axes {position_axes}: a subset of 0, 1, 2")
    batch = len(q_rad)
    q = _float64(q_rad, "q_rad", (batch, n))
    target_position = _float64(target_position_m, "target_position_m", (m_position,))
    error = np.empty((batch, m))
    jacobian = np.empty((batch, m, n))
    if batch:
        _native.task_residual(
            _float64(fixed, "fixed", (n, 4, 4)), _float64(tip, "tip", (4, 4)), q, n, batch,
            np.array(rows, dtype=np.int64), m, m_position, target_position, rotation,
            target_rotation is not None, error, jacobian,
        )  # fmt: skip
    return error, jacobian


def newton(
    fixed: FloatArray,  # (n, 4, 4) as `chain_kinematics`
    tip: FloatArray,  # (4, 4)
    position_axes: list[int],
    target_position_m: FloatArray,  # (len(position_axes),)
    target_rotation: OrientationTarget,  # as `task_residual`
    q_rad: FloatArray,  # (B, n) evaluated: error and jacobian are measured there
    error: FloatArray,  # (B, m)
    jacobian: FloatArray,  # (B, m, n)
    iterations: int,
    damping: float,
    until: float | None = None,
    locked: BoolArray | None = None,  # (B, n) joints a row holds fixed (DLS steps)
    tangent: FloatArray | None = None,  # (B, n) bordered steps [J; t^T] dq = [e; 0] (r = 1)
    fresh: BoolArray | None = None,  # (B,) rows not yet evaluated: their error and J unread
    threads: int = 1,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # q (B, n), error (B, m), jacobian (B, m, n)
    """Up to `iterations` Newton steps per row, each evaluated by the task residual, as
    `correction.iterate` takes them with `fibre`'s step rules: a DLS step with the locked
    joints' columns zeroed, or with `tangent` the bordered step; with `until`, a row stops
    once |e| <= until (a NaN |e| never does); a step entry that is not finite makes its
    joint NaN. A `fresh` row is evaluated first (its given error and Jacobian are not
    read). The inputs are not changed. With `threads` > 1 and enough rows (`helper_rows`)
    the first part of the rows runs on the row helper: the same numbers."""
    n = len(fixed)
    orientation_rows, rotation = _orientation(target_rotation)
    rows = [*position_axes, *orientation_rows]
    m, m_position = len(rows), len(position_axes)
    if not 0 < n <= MAX_JOINTS or not 0 < m <= MAX_TASK_DIMENSION:
        raise ValueError(f"a task of {m} rows on {n} joints; the kernel takes 1 to 6 on 1 to 64")
    if tangent is not None and m != n - 1:
        raise ValueError(f"a tangent step needs n - 1 task rows, got {m} on {n} joints")
    if tangent is None and not damping > 0.0:
        raise ValueError(f"a DLS step needs a positive damping, got {damping}")
    batch = len(q_rad)
    q = np.array(_float64(q_rad, "q_rad", (batch, n)))
    e = np.array(_float64(error, "error", (batch, m)))
    j = np.array(_float64(jacobian, "jacobian", (batch, m, n)))
    lock = (
        np.zeros(1, dtype=np.uint8)
        if locked is None
        else np.ascontiguousarray(np.broadcast_to(locked, (batch, n)), dtype=np.uint8)
    )
    border = np.zeros(1) if tangent is None else _float64(tangent, "tangent", (batch, n))
    fresh_rows = (
        np.zeros(1, dtype=np.uint8)
        if fresh is None
        else np.ascontiguousarray(np.broadcast_to(fresh, (batch,)), dtype=np.uint8)
    )
    first = helper_rows(batch, threads)
    if batch and (iterations > 0 or fresh is not None):
        _native.newton(
            _float64(fixed, "fixed", (n, 4, 4)), _float64(tip, "tip", (4, 4)), n,
            np.array(rows, dtype=np.int64), m, m_position,
            _float64(target_position_m, "target_position_m", (m_position,)), rotation,
            target_rotation is not None, q, e, j, batch, iterations,
            -1.0 if until is None else float(until), float(damping), lock, locked is not None,
            border, tangent is not None, fresh_rows, fresh is not None,
            np.empty((m + 3) * n * (2 if first else 1)), first,
        )  # fmt: skip
    return q, e, j


def smallest_singular_values(jacobian: FloatArray) -> FloatArray:  # (B, m, n), m <= n -> (B,)
    """sigma_min of each row's J by one-sided Jacobi on its rows (as accurate as an SVD:
    to about eps x sigma_max); NaN for a row with a non-finite entry."""
    batch, m, n = jacobian.shape
    if not 0 < m <= n:
        raise ValueError(f"a Jacobian of {m} rows on {n} columns; the kernel takes 1 to n rows")
    sigma = np.empty(batch)
    if batch:
        j = _float64(jacobian, "jacobian", (batch, m, n))
        _native.smallest_singular_values(j, batch, m, n, sigma, np.empty(m * n))
    return sigma


def set_helper_spin(seconds: float) -> float:
    """How long the compiled kernels' row helper (row_helper.h) spins for its next part
    before it sleeps; returns the value it replaces. ValueError below 0 or above 1 s."""
    return float(_native.helper_spin(float(seconds)))


def helper_parts() -> int:
    """The parts of split calls the row helper (row_helper.h) has done in this process."""
    return int(_native.helper_parts())


def least_singular_value(jacobian: FloatArray) -> float:  # (B, m, n), m <= n
    """The least of `smallest_singular_values` over the rows with no non-finite entry (+inf
    for none), the same number at a fraction of the cost: each row's bound from the
    Cholesky factor of J J^T orders the rows, and the exact values are computed only
    until the next row's bound is above the least found."""
    batch, m, n = jacobian.shape
    if not 0 < m <= n:
        raise ValueError(f"a Jacobian of {m} rows on {n} columns; the kernel takes 1 to n rows")
    j = _float64(jacobian, "jacobian", (batch, m, n))
    return float(_native.least_singular_value(j, batch, m, n))


@dataclass(frozen=True)
class WalkRules:
    """trace/walk.py's constants, passed down so that they are written once."""

    step_rad: float  # h
    corrector_iterations: int
    max_steps: int
    meet_factor: float
    twin_sigma: float
    twin_offset: float


@dataclass(frozen=True)
class Walked:
    """Every point the fronts moved to, in the order they moved, and how the walk ended."""

    q_rad: FloatArray  # (T, n)
    error: FloatArray  # (T, m)
    jacobian: FloatArray  # (T, m, n)
    tangent: FloatArray  # (T, n)
    front: IntArray  # (T,) the front that moved there
    partner: IntArray  # (F,) the front each met, -1 for none
    expired: bool  # the deadline passed before the walk was over


def walk(
    fixed: FloatArray,  # (n, 4, 4) as `chain_kinematics`
    tip: FloatArray,  # (4, 4)
    position_axes: list[int],
    target_position_m: FloatArray,
    target_rotation: OrientationTarget,  # as `task_residual`
    q_rad: FloatArray,  # (F, n) front ends, evaluated
    tangent: FloatArray,  # (F, n) their directions of travel
    jacobian: FloatArray,  # (F, n - 1, n) at the ends
    rules: WalkRules,
    damping: float,
    expires_at_s: float,  # time.monotonic() after which the walk stops (inf: never)
    capacity: int | None = None,  # output rows to start with (None: 16 per front)
) -> Walked:
    """trace/walk.py's fronts walked in lockstep, every step and meeting as `walk_fronts`
    takes them (its numpy loop is the reference this is pinned to), compiled. The output
    rows grow as needed: the walk pauses when a step might not fit and goes on."""
    n = len(fixed)
    orientation_rows, rotation = _orientation(target_rotation)
    rows = [*position_axes, *orientation_rows]
    m, m_position = len(rows), len(position_axes)
    if not 0 < n <= MAX_JOINTS or m != n - 1:
        raise ValueError(
            f"a walk needs n - 1 task rows on 1 to {MAX_JOINTS} joints, got {m} on {n}"
        )
    fronts = len(q_rad)
    q = np.array(_float64(q_rad, "q_rad", (fronts, n)))
    t = np.array(_float64(tangent, "tangent", (fronts, n)))
    j = np.array(_float64(jacobian, "jacobian", (fronts, m, n)))
    step = np.full(fronts, rules.step_rad)
    alive = np.ones(fronts, dtype=np.uint8)
    partner = np.full(fronts, -1, dtype=np.int64)
    constants = (
        _float64(fixed, "fixed", (n, 4, 4)), _float64(tip, "tip", (4, 4)), n,
        np.array(rows, dtype=np.int64), m, m_position,
        _float64(target_position_m, "target_position_m", (m_position,)), rotation,
        target_rotation is not None, fronts, q, t, j, step, alive, partner, rules.step_rad,
        float(damping), rules.meet_factor, rules.twin_sigma, rules.twin_offset,
        rules.corrector_iterations,
    )  # fmt: skip
    capacity = max(16 * fronts, 1) if capacity is None else max(capacity, fronts, 1)
    out = _WalkRows(capacity, m, n)
    count, steps, status = 0, 0, 1
    while status == 1:
        if count + fronts > capacity:
            capacity *= 2
            out = out.grown(capacity, count)
        status, count, taken = _native.walk(
            *constants, rules.max_steps - steps, expires_at_s,
            out.q, out.error, out.jacobian, out.tangent, out.front, capacity, count,
        )  # fmt: skip
        steps += taken
    return Walked(
        q_rad=out.q[:count], error=out.error[:count], jacobian=out.jacobian[:count],
        tangent=out.tangent[:count], front=out.front[:count], partner=partner,
        expired=status == 2,
    )  # fmt: skip


class _WalkRows:
    """The walk's output rows, `capacity` of them."""

    def __init__(self, capacity: int, m: int, n: int) -> None:
        self.q = np.empty((capacity, n))
        self.error = np.empty((capacity, m))
        self.jacobian = np.empty((capacity, m, n))
        self.tangent = np.empty((capacity, n))
        self.front = np.empty(capacity, dtype=np.int64)

    def grown(self, capacity: int, count: int) -> _WalkRows:
        """A larger set of rows holding the first `count` of these."""
        bigger = _WalkRows(capacity, self.error.shape[1], self.q.shape[1])
        for name in ("q", "error", "jacobian", "tangent", "front"):
            getattr(bigger, name)[:count] = getattr(self, name)[:count]
        return bigger


@dataclass(frozen=True)
class SelfBodies:
    """What collision/check.py's `free` needs for self-collision alone (robot.py's arrays)."""

    joint_origin: FloatArray  # (n, 4, 4) as `chain_frames`
    joint_axis: FloatArray  # (n, 3)
    frame: IntArray  # (K,) the chain frame each body moves with
    centre_local_m: FloatArray  # (K, S, 3)
    radius_m: FloatArray  # (K, S)
    own_spheres: IntArray  # (K,)
    bound_local_m: FloatArray  # (K, 3)
    bound_radius_m: FloatArray  # (K,)
    pair_a: IntArray  # (P,)
    pair_b: IntArray  # (P,)
    hull_local_m: FloatArray  # (K, S, V, 3) padded with each hull's first vertex
    hull_count: IntArray  # (K, S)
    hull_pad_m: FloatArray  # (K, S)
    margin_m: float


@dataclass(frozen=True)
class CompiledSpace:
    """A FibreSpace as the compiled walks take it (space.py's `compiled`): a serial chain's
    fibre, its limits and coaxial sets, and its collision check: self-collision, a scene's
    obstacles, both or neither."""

    fixed: FloatArray  # (n, 4, 4) as `chain_kinematics`
    tip: FloatArray  # (4, 4)
    position_axes: list[int]
    target_position_m: FloatArray
    target_rotation: OrientationTarget  # as `task_residual`
    damping: float  # the DLS steps' (above 0)
    lower_rad: FloatArray  # (n,)
    upper_rad: FloatArray  # (n,)
    periodic: BoolArray  # (n,)
    set_joint: IntArray  # (C,) the coaxial sets' joints
    set_angle_rad: FloatArray  # (C,) and angles
    bodies: SelfBodies | None  # the robot's bodies; None: no collision check
    check_self: bool = True  # self-collision checked on `bodies` (False: the obstacles only)
    obstacles: ObstacleSet | None = None  # checked against the bodies `moving`
    moving: IntArray | None = None  # (M,) the bodies that move

    def arguments(self) -> tuple[tuple[object, ...], list[int]]:
        """The C arguments every walk takes, checked, and (n, m, m_position, orientation,
        sets, check_self, K, S, P, V) for its sizes."""
        n = len(self.fixed)
        orientation_rows, rotation = _orientation(self.target_rotation)
        rows = [*self.position_axes, *orientation_rows]
        m, m_position = len(rows), len(self.position_axes)
        if not 0 < n <= MAX_JOINTS or not 0 < m <= MAX_TASK_DIMENSION:
            raise ValueError(
                f"a task of {m} rows on {n} joints; the kernel takes 1 to 6 on 1 to 64"
            )
        if not self.damping > 0.0:
            raise ValueError(f"a DLS step needs a positive damping, got {self.damping}")
        sets = len(self.set_joint)
        joints = _int64(self.set_joint, "set_joint", (sets,))
        if sets and (joints.min() < 0 or joints.max() >= n):
            raise ValueError(f"coaxial set joints must lie in 0 to {n - 1}")
        chain = (
            _float64(self.fixed, "fixed", (n, 4, 4)), _float64(self.tip, "tip", (4, 4)),
            np.array(rows, dtype=np.int64),
            _float64(self.target_position_m, "target_position_m", (m_position,)), rotation,
            _float64(self.lower_rad, "lower_rad", (n,)),
            _float64(self.upper_rad, "upper_rad", (n,)),
            np.ascontiguousarray(self.periodic, dtype=np.uint8), joints,
            _float64(self.set_angle_rad, "set_angle_rad", (sets,)),
        )  # fmt: skip
        if self.bodies is None:
            none = (np.zeros(1), np.zeros(1, dtype=np.int64))
            body_arguments: tuple[object, ...] = (
                np.zeros((n, 4, 4)), np.zeros((n, 3)), none[1], none[0], none[0], none[1],
                none[0], none[0], none[1], none[1], none[0], none[1], none[0],
            )  # fmt: skip
            body_sizes = [0, 0, 1, 0, 1]
        else:
            body_arguments, body_sizes = _body_arguments(self.bodies, n)
            body_sizes[0] = int(self.check_self)
        sizes = [n, m, m_position, self.target_rotation is not None, sets, *body_sizes]
        return (*chain, *body_arguments, *self._scene_arguments()), sizes

    def _scene_arguments(self) -> tuple[object, ...]:
        """The moving bodies (M,) and the obstacles' six arrays (scene.py): empty for none."""
        if self.obstacles is None or self.bodies is None or self.moving is None:
            return (np.zeros(0, dtype=np.int64), *ObstacleSet.empty().arguments()[:-1])
        count = len(self.bodies.centre_local_m)
        moving = _int64(self.moving, "moving", (len(self.moving),))
        if len(moving) and (moving.min() < 0 or moving.max() >= count):
            raise ValueError(f"moving must index bodies 0 to {count - 1}")
        return (moving, *self.obstacles.arguments()[:-1])

    def scene_sizes(self) -> tuple[int, int]:
        """(M, O): the moving bodies and the obstacles the walks check."""
        if self.obstacles is None or self.moving is None:
            return 0, 0
        return len(self.moving), len(self.obstacles.shape)

    def margin_m(self) -> float:
        return 0.0 if self.bodies is None else float(self.bodies.margin_m)


@dataclass(frozen=True)
class PlannerRules:
    """local_planner.py's constants for one batch of edges, passed down once."""

    delta_rad: float  # step along the segment
    stretch: float  # largest step and path length, in delta and chord units (lambda)
    tolerance: float  # |e| a projected step must reach
    iterations: int  # Newton steps per projected step ...
    extra_iterations: int  # ... and up to this many more for a step not yet converged
    max_steps: int  # steps an edge may take
    set_iterations: int = 4  # Newton steps onto a coaxial set at a crossing (space.py)
    limit_check_rad: float = 0.0  # space.py's `inside_between` spacing (0: none)


@dataclass(frozen=True)
class PlannedWalks:
    """Where each edge's walk went, as local_planner.Walks has it, and whether the
    deadline passed before every edge was walked."""

    reached: BoolArray  # (E,)
    points_rad: list[FloatArray]  # per edge (k_e, n), empty unless recorded
    expired: bool


# Walks a thread must have to take some: one walk on the fibre is tens of microseconds
# (an iiwa14 position edge about 20), a thread's hand-off about as much.
MIN_CHUNK_WALKS = 8


def projected_walk(
    space: CompiledSpace,
    q_from_rad: FloatArray,  # (E, n) valid configurations
    goal_rad: FloatArray,  # (E, n) each edge's end, unwrapped toward its start
    chord_rad: FloatArray,  # (E,) |goal - q_from|
    rules: PlannerRules,
    expires_at_s: float,  # time.monotonic() after which the walks stop (inf: never)
    record: bool,
    threads: int = 1,
) -> PlannedWalks:
    """local_planner.py's `walk_on_fibre`, each edge whole in compiled code: the same
    projected steps and validity tests (space.py's motion_valid with its coaxial crossings,
    and collision/check.py's `free` for self-collision, the hulls deciding where the
    spheres are within the margin), in the same order, as its numpy loop, which is the
    reference it is pinned to. With `threads` > 1 the first edges run on the row helper
    (rows.helper_rows; each walk is its own)."""
    arguments, sizes = space.arguments()
    n, m = sizes[0], sizes[1]
    edges = len(q_from_rad)
    numbers = np.array(
        [space.damping, rules.delta_rad, rules.stretch, rules.tolerance, space.margin_m(),
         expires_at_s, rules.limit_check_rad]
    )  # fmt: skip
    counts_of = [rules.iterations, rules.extra_iterations, rules.set_iterations, rules.max_steps]
    reached = np.zeros(edges, dtype=np.uint8)
    counts = np.zeros(edges, dtype=np.int64)
    points = np.empty((edges, rules.max_steps if record else 0, n))
    q_from = _float64(q_from_rad, "q_from_rad", (edges, n))
    goal = _float64(goal_rad, "goal_rad", (edges, n))
    chord = _float64(chord_rad, "chord_rad", (edges,))

    # The first edges on the row helper (rows.helper_rows), with scratch of their own.
    first = helper_rows(edges, threads, MIN_CHUNK_WALKS)
    call_sizes = np.array([*sizes, *counts_of, edges, record, first], dtype=np.int64)
    scratch = _native.walk_scratch(n, m, sizes[6], sizes[7], *space.scene_sizes())
    work = np.empty(scratch * (2 if first else 1))
    written = points if record else np.empty((1, n))
    expired = bool(edges) and bool(
        _native.projected_walk(
            numbers, call_sizes, *arguments, q_from, goal, chord, reached, written, counts, work
        )
    )
    if not record:
        return PlannedWalks(reached.astype(bool), [], expired)
    return PlannedWalks(
        reached.astype(bool), [points[e, : counts[e]].copy() for e in range(edges)], expired
    )


@dataclass(frozen=True)
class SteerRules:
    """steering.py's constants, passed down once."""

    step_rad: float  # longest step along the tangent
    max_steps: int
    stretch: float  # a projected step may move at most stretch x step_rad
    tolerance: float  # |e| a projected step must reach
    iterations: int  # Newton steps per projected step (stopping once within tolerance)
    stall_steps: int  # end a walk that got no nearer over this many steps ...
    min_progress_rad: float  # ... by at least this much
    set_iterations: int = 4  # Newton steps onto a coaxial set at a crossing (space.py)
    limit_check_rad: float = 0.0  # space.py's `inside_between` spacing (0: none)


@dataclass(frozen=True)
class Steered:
    """Where each walk ended (unwrapped) and whether it arrived; whether the deadline
    passed before every walk was over."""

    q_end_rad: FloatArray  # (E, n)
    arrived: BoolArray  # (E,)
    expired: bool


def steer_walk(
    space: CompiledSpace,
    q_from_rad: FloatArray,  # (E, n) valid configurations
    goal_rad: FloatArray,  # (E, n) unwrapped toward each start
    rules: SteerRules,
    expires_at_s: float,
    threads: int = 1,
) -> Steered:
    """steering.py's `steer`, each walk whole in compiled code: the direction to the goal
    projected onto J's null space with the joints pushed out of a limit held, the step
    clipped to the limits and projected back with those joints locked, and the planner's
    validity tests, in the same order as its numpy loop, which it is pinned to. With
    `threads` > 1 the first walks run on the row helper (rows.helper_rows; each is its
    own)."""
    arguments, sizes = space.arguments()
    n, m = sizes[0], sizes[1]
    walks = len(q_from_rad)
    numbers = np.array(
        [space.damping, rules.step_rad, rules.stretch, rules.tolerance, space.margin_m(),
         expires_at_s, rules.limit_check_rad, rules.min_progress_rad]
    )  # fmt: skip
    counts_of = [rules.iterations, rules.stall_steps, rules.set_iterations, rules.max_steps]
    q = np.array(_float64(q_from_rad, "q_from_rad", (walks, n)))
    goal = _float64(goal_rad, "goal_rad", (walks, n))
    arrived = np.zeros(walks, dtype=np.uint8)

    first = helper_rows(walks, threads, MIN_CHUNK_WALKS)
    call_sizes = np.array([*sizes, *counts_of, walks, 0, first], dtype=np.int64)
    scratch = _native.walk_scratch(n, m, sizes[6], sizes[7], *space.scene_sizes())
    work = np.empty(scratch * (2 if first else 1))
    expired = bool(walks) and bool(
        _native.steer_walk(numbers, call_sizes, *arguments, goal, q, arrived, work)
    )
    return Steered(q, arrived.astype(bool), expired)


def _body_arguments(bodies: SelfBodies, n: int) -> tuple[tuple[object, ...], list[int]]:
    """The C arguments of self-collision on `bodies` (n joints), checked, and (check_self,
    K, S, P, V) for the kernels' sizes."""
    count, spheres = len(bodies.centre_local_m), bodies.centre_local_m.shape[1]
    width = bodies.hull_local_m.shape[2]
    checked = _Bodies.of(
        bodies.centre_local_m, bodies.radius_m, bodies.own_spheres, bodies.bound_local_m,
        bodies.bound_radius_m, bodies.pair_a, bodies.pair_b,
    )  # fmt: skip
    frames = _int64(bodies.frame, "frame", (count,))
    if count and (frames.min() < 0 or frames.max() > n):
        raise ValueError(f"body frames must lie in 0 to {n}")
    hull_count = _int64(bodies.hull_count, "hull_count", (count, spheres))
    if count and (hull_count.min() < 1 or hull_count.max() > width):
        raise ValueError(f"hull vertex counts must lie in 1 to {width}")
    _, centre, radius, own, bound, bound_radius, pair_a, pair_b, _ = checked.arguments
    arguments = (
        _float64(bodies.joint_origin, "joint_origin", (n, 4, 4)),
        _float64(bodies.joint_axis, "joint_axis", (n, 3)),
        frames, centre, radius, own, bound, bound_radius, pair_a, pair_b,
        _float64(bodies.hull_local_m, "hull_local_m", (count, spheres, width, 3)),
        hull_count, _float64(bodies.hull_pad_m, "hull_pad_m", (count, spheres)),
    )  # fmt: skip
    return arguments, [1, count, spheres, len(bodies.pair_a), width]


def refined_self_clearance_at_m(
    bodies: SelfBodies,
    q_rad: FloatArray,  # (B, n)
) -> FloatArray:  # (B,)
    """robot.py's `refined_self_clearance_m` at joint values (bodies.margin_m its margin),
    row by row in compiled code: the same numbers (the hulls decide the sphere pairs
    within the margin, each configuration's deepest pair first), and no (pairs, S, S, 3)
    temporaries, which for a few hundred configurations near themselves took tens of MiB."""
    n = len(bodies.joint_origin)
    batch = len(q_rad)
    body_arguments, body_sizes = _body_arguments(bodies, n)
    chain = (
        np.zeros((n, 4, 4)), np.eye(4), np.zeros(1, dtype=np.int64), np.zeros(1), np.eye(3),
        np.zeros(n), np.zeros(n), np.zeros(n, dtype=np.uint8), np.zeros(1, dtype=np.int64),
        np.zeros(1),
    )  # fmt: skip
    _, count, spheres, pairs, _ = body_sizes
    numbers = np.array([0.0, 0.0, 0.0, 0.0, float(bodies.margin_m), np.inf, 0.0])
    sizes = np.array([n, 1, 1, 0, 0, *body_sizes, 0, 0, 0, 0, batch, 0], dtype=np.int64)
    clearance = np.empty(batch)
    if batch:
        _native.refined_self_clearance(
            numbers, sizes, *chain, *body_arguments, np.zeros(0, dtype=np.int64),
            *ObstacleSet.empty().arguments()[:-1], _float64(q_rad, "q_rad", (batch, n)),
            clearance, np.empty(4 * max(pairs * spheres * spheres, 1)),
            np.empty(_native.walk_scratch(n, 1, count, spheres)),
        )  # fmt: skip
    return clearance


def nearest_segment(
    q_rad: FloatArray,  # (K, n)
    points_rad: FloatArray,  # (P, n) every path's points
    before: IntArray,  # (P,) each point's neighbours along its path (itself at an open end)
    after: IntArray,  # (P,)
    nearest: IntArray,  # (K, k) rows of points_rad, each row's candidates (-1: none)
    periodic: BoolArray,  # (n,)
) -> tuple[FloatArray, IntArray]:  # (K,) least distance, (K,) the point beside it
    """For each configuration, the least joint-metric distance to the segments from each
    candidate point to its neighbours along its path (curves.segment_distance, wrapped on
    the periodic joints), and the first candidate that reaches it; +inf and -1 where no
    distance is finite."""
    count, n = q_rad.shape
    k = nearest.shape[1] if nearest.ndim == 2 else 0
    if n > MAX_JOINTS:
        raise ValueError(f"{n} joints; the kernel takes at most {MAX_JOINTS}")
    size = len(points_rad)
    indices = (_int64(before, "before", (size,)), _int64(after, "after", (size,)))
    picked = _int64(nearest, "nearest", (count, k))
    if count and k and (picked.min() < -1 or picked.max() >= size):
        raise ValueError(f"nearest must index the {size} points (or be -1: no candidate)")
    if size and (min(i.min() for i in indices) < 0 or max(i.max() for i in indices) >= size):
        raise ValueError(f"before and after must index the {size} points")
    distance, point = np.full(count, np.inf), np.full(count, -1, dtype=np.int64)
    if count and k:
        _native.nearest_segment(
            _float64(q_rad, "q_rad", (count, n)), _float64(points_rad, "points_rad", (size, n)),
            *indices, picked, np.ascontiguousarray(periodic, dtype=np.uint8), count, k, n,
            distance, point,
        )  # fmt: skip
    return distance, point


def nearest_in_group(
    points_rad: FloatArray,  # (P, n) sorted by group
    point_group: IntArray,  # (P,) ascending, each in [0, G)
    queries_rad: FloatArray,  # (Q, n)
    query_group: IntArray,  # (Q,) each in [0, G)
    periodic: BoolArray,  # (n,)
) -> IntArray:  # (Q,) row of points_rad, -1 where the query's group has no point
    """Each query's nearest point of its own group (joint metric, wrapped on the periodic
    joints; the first of equally near ones), by brute force within the group: a component's
    members against its own path points, tens against hundreds, which a KD-tree over every
    component's points answers more slowly."""
    size, n = points_rad.shape
    count = len(queries_rad)
    if n > MAX_JOINTS:
        raise ValueError(f"{n} joints; the kernel takes at most {MAX_JOINTS}")
    groups = _int64(point_group, "point_group", (size,))
    if size and np.any(np.diff(groups) < 0):
        raise ValueError("point_group must be sorted ascending")
    asked = _int64(query_group, "query_group", (count,))
    if count and asked.min() < 0:
        raise ValueError("query_group must be >= 0")
    highest = max(int(groups.max(initial=-1)), int(asked.max(initial=-1)))
    start = np.searchsorted(groups, np.arange(highest + 2)).astype(np.int64)  # (G + 1,)
    nearest = np.full(count, -1, dtype=np.int64)
    if count:
        _native.nearest_in_group(
            _float64(points_rad, "points_rad", (size, n)), start,
            _float64(queries_rad, "queries_rad", (count, n)), asked,
            np.ascontiguousarray(periodic, dtype=np.uint8), count, n, nearest,
        )  # fmt: skip
    return nearest


def along(tangent: FloatArray, direction: FloatArray) -> FloatArray:  # (K, n) -> (K, n)
    """Each tangent with the sign that points it along `direction`; where the tangent is
    not finite (a rank-deficient Jacobian), the unit direction itself."""
    count, n = direction.shape
    if n > MAX_JOINTS:
        raise ValueError(f"{n} joints; the kernel takes at most {MAX_JOINTS}")
    out = np.empty((count, n))
    if count:
        _native.along(
            _float64(tangent, "tangent", (count, n)), _float64(direction, "direction", (count, n)),
            count, n, out,
        )  # fmt: skip
    return out


def hermite(
    p0: FloatArray,  # (K, n)
    t0: FloatArray,  # (K, n) unit tangent at p0, pointing toward p1
    p1: FloatArray,  # (K, n)
    t1: FloatArray,  # (K, n) unit tangent at p1, pointing away from p0
    s: FloatArray,  # (K,) in [0, 1]
) -> tuple[FloatArray, FloatArray]:  # (K, n) points, (K, n) unit directions of the curve
    """The cubic Hermite curve from p0 to p1 with end tangents t0, t1 scaled by the chord
    length, at parameter s: off a smooth curve by O(L^4) where the chord is off by O(L^2)
    (the trace's guesses between its points, connect/trace/)."""
    count, n = p0.shape
    if n > MAX_JOINTS:
        raise ValueError(f"{n} joints; the kernel takes at most {MAX_JOINTS}")
    point, direction = np.empty((count, n)), np.empty((count, n))
    if count:
        _native.hermite(
            _float64(p0, "p0", (count, n)), _float64(t0, "t0", (count, n)),
            _float64(p1, "p1", (count, n)), _float64(t1, "t1", (count, n)),
            _float64(s, "s", (count,)), count, n, point, direction,
        )  # fmt: skip
    return point, direction


def settle_dense(
    q_rad: FloatArray,  # (D, n) the dense points after Newton
    placed_rad: FloatArray,  # (D, n) where each was placed before
    window_low_rad: FloatArray,  # (n,)
    lower_rad: FloatArray,  # (n,)
    upper_rad: FloatArray,  # (n,)
    periodic: BoolArray,  # (n,)
    stray_rad: float,
    fixed_rows: IntArray,  # (F,) rows set to `fixed_rad` once in the window
    fixed_rad: FloatArray,  # (F, n)
    excluded_rows: IntArray,  # (E,) rows never inside
) -> tuple[FloatArray, BoolArray]:  # (D, n) wrapped, (D,) inside
    """densify.py's last pass: each point into the 2 pi window from `window_low_rad`, the
    fixed rows set, then inside = within the limits, not carried more than `stray_rad`
    from where it was placed and not excluded; the periodic joints wrapped."""
    count, n = q_rad.shape
    fixed, excluded = (
        _int64(fixed_rows, "fixed_rows", (len(fixed_rows),)),
        _int64(excluded_rows, "excluded_rows", (len(excluded_rows),)),
    )
    for name, rows in (("fixed_rows", fixed), ("excluded_rows", excluded)):
        if len(rows) and (rows.min() < 0 or rows.max() >= count):
            raise ValueError(f"{name} must index the {count} points")
    q = np.array(q_rad, dtype=np.float64, order="C")  # (D, n) a copy, settled in place
    inside = np.zeros(count, dtype=np.uint8)
    if count:
        _native.settle_dense(
            q, _float64(placed_rad, "placed_rad", (count, n)),
            *(_float64(v, name, (n,)) for v, name in (
                (window_low_rad, "window_low_rad"), (lower_rad, "lower_rad"),
                (upper_rad, "upper_rad"),
            )),
            np.ascontiguousarray(periodic, dtype=np.uint8), count, n, float(stray_rad),
            fixed, _float64(fixed_rad, "fixed_rad", (len(fixed), n)), len(fixed),
            excluded, len(excluded), inside,
        )  # fmt: skip
    return q, inside.astype(bool)


def chain_fronts(
    q_rad: FloatArray,  # (T, n) the seeds (first S rows), then every point the fronts reached
    seeds: int,  # S
    by_front: IntArray,  # (T - S,) the front that reached each, in travel order
    partner: IntArray,  # (2 S,) the front each met, -1: none
) -> tuple[IntArray, IntArray, BoolArray]:  # rows (P,), first (C + 1,), closed (C,)
    """strands.py's fronts chained through their seeds and meetings into ordered curves:
    the curves' rows of `q_rad`, curve after curve, where each starts, and which close."""
    total, n = q_rad.shape
    reached, fronts = total - seeds, 2 * seeds
    by_front = _int64(by_front, "by_front", (reached,))
    partner = _int64(partner, "partner", (fronts,))
    if np.any((by_front < 0) | (by_front >= fronts)) or np.any(partner >= fronts):
        raise ValueError(f"fronts must be numbered below {fronts}")
    rows, first = np.empty(total, np.int64), np.empty(seeds + 1, np.int64)
    closed = np.empty(seeds, np.uint8)
    curves = _native.chain_fronts(
        _float64(q_rad, "q_rad", (total, n)), total, n, seeds, by_front, partner,
        np.empty(fronts + 1, np.int64), np.empty(reached, np.int64), np.empty(seeds, np.uint8),
        np.empty(fronts, np.uint8), np.empty(total, np.int64), np.empty(total, np.int64),
        rows, first, closed,
    )  # fmt: skip
    return rows[: first[curves]], first[: curves + 1], closed[:curves].astype(bool)


def unwrap_curves(
    q_rad: FloatArray,  # (T, n)
    rows: IntArray,  # (P,) each curve's rows in order, curve after curve
    first: IntArray,  # (C + 1,)
) -> FloatArray:  # (P, n)
    """points.py's `unwrap` of each curve: its points made continuous, every step the short
    way round the torus, to the bit."""
    total, n = q_rad.shape
    count = len(rows)
    rows = _int64(rows, "rows", (count,))
    first = _int64(first, "first", (len(first),))
    if len(first) < 1 or first[0] != 0 or first[-1] != count or np.any(np.diff(first) < 0):
        raise ValueError(f"first must run from 0 to the {count} rows, never back")
    if count and (rows.min() < 0 or rows.max() >= total):
        raise ValueError(f"rows must index the {total} points")
    out = np.empty((count, n))
    _native.unwrap_curves(_float64(q_rad, "q_rad", (total, n)), rows, first, len(first) - 1, n, out)
    return out


def cut_runs(
    points_rad: FloatArray,  # (P, n) every curve's points, unwrapped along it
    rows: IntArray,  # (P,) their evaluated rows
    first: IntArray,  # (C + 1,) curve c is [first[c], first[c + 1])
    closed: BoolArray,  # (C,)
    window_low_rad: FloatArray,  # (n,)
    lower_rad: FloatArray,  # (n,)
    upper_rad: FloatArray,  # (n,)
    periodic: BoolArray,  # (n,)
) -> tuple[FloatArray, IntArray, IntArray, BoolArray, FloatArray, BoolArray]:
    """cut.py's runs of consecutive points inside the limits, run after run: their points
    (P', n) and rows (P',), where each starts (R + 1,), closed (R,), and the outside point
    before and after each (R, 2, n) where there is one (R, 2); a closed curve that leaves
    the limits turned to start outside, the points past its start moved on by its turns."""
    count, n = points_rad.shape
    curves = len(first) - 1
    if n > MAX_JOINTS:
        raise ValueError(f"{n} joints; the kernel takes at most {MAX_JOINTS}")
    first = _int64(first, "first", (curves + 1,))
    if curves < 0 or first[0] != 0 or first[-1] != count or np.any(np.diff(first) < 0):
        raise ValueError(f"first must run from 0 to the {count} points, never back")
    out_points, out_rows = np.empty((count, n)), np.empty(count, dtype=np.int64)
    run_first = np.zeros(count + 1, dtype=np.int64)
    run_closed = np.zeros(count, dtype=np.uint8)
    exits, has_exit = np.full((count, 2, n), np.nan), np.zeros((count, 2), dtype=np.uint8)
    runs = _native.cut_runs(
        _float64(points_rad, "points_rad", (count, n)), _int64(rows, "rows", (count,)), first,
        np.ascontiguousarray(closed, dtype=np.uint8).reshape(curves), curves, n,
        *(_float64(v, name, (n,)) for v, name in (
            (window_low_rad, "window_low_rad"), (lower_rad, "lower_rad"),
            (upper_rad, "upper_rad"),
        )),
        np.ascontiguousarray(periodic, dtype=np.uint8), np.empty(count, dtype=np.uint8),
        out_points, out_rows, run_first, run_closed, exits, has_exit,
    )  # fmt: skip
    size = run_first[runs]
    return (
        out_points[:size], out_rows[:size], run_first[: runs + 1], run_closed[:runs].astype(bool),
        exits[:runs], has_exit[:runs].astype(bool),
    )  # fmt: skip


@dataclass(frozen=True)
class DenseNodes:
    """densify.py's nodes (N), run after run: each run's refined start, its points, its
    refined end, and for a closed run its first point again."""

    q_rad: FloatArray  # (N, n) unwrapped along each run
    row: IntArray  # (N,) evaluated row; T + l for refined limit point l
    run: IntArray  # (N,)
    kind: IntArray  # (N,) 0 a point Newton moves, 1 a limit point, 2 a closing repeat
    inner: IntArray  # (N,) inner points in the segment after the node
    dense: int  # nodes and inner points in all


def dense_nodes(
    points_rad: FloatArray,  # (P, n) the runs' points, unwrapped along each
    rows: IntArray,  # (P,) their evaluated rows
    first: IntArray,  # (R + 1,)
    closed: BoolArray,  # (R,)
    limit_of: IntArray,  # (2 R,) each run's refined start and end: a row of found, -1: none
    found_rad: FloatArray,  # (L, n) the refined limit points, unwrapped like their runs
    evaluated: int,  # T, the evaluated rows (a limit point's row is T + its index)
    spacing_rad: float,
) -> DenseNodes:
    """densify.py's nodes and how many inner points each segment gets:
    ceil(|chord| / (0.9 spacing)) - 1, at least 0, none after a run's last node."""
    count, n = points_rad.shape
    runs = len(closed)
    if n > MAX_JOINTS:
        raise ValueError(f"{n} joints; the kernel takes at most {MAX_JOINTS}")
    first = _int64(first, "first", (runs + 1,))
    limit_of = _int64(limit_of, "limit_of", (2 * runs,))
    found_rad = _float64(found_rad, "found_rad", (len(found_rad), n))
    if runs and (first[0] != 0 or first[-1] != count or np.any(np.diff(first) < 1)):
        raise ValueError(f"first must run from 0 to the {count} points, a point a run at least")
    if np.any(limit_of >= len(found_rad)):
        raise ValueError(f"limit_of must index the {len(found_rad)} limit points")
    nodes = count + int(np.sum(limit_of >= 0)) + int(np.sum(closed))
    q, row, run = np.empty((nodes, n)), np.empty(nodes, np.int64), np.empty(nodes, np.int64)
    kind, inner = np.empty(nodes, np.uint8), np.empty(nodes, np.int64)
    dense = _native.dense_nodes(
        _float64(points_rad, "points_rad", (count, n)), _int64(rows, "rows", (count,)), first,
        np.ascontiguousarray(closed, dtype=np.uint8), runs, n, limit_of, found_rad,
        int(evaluated), float(spacing_rad), q, row, run, kind, inner,
    )  # fmt: skip
    return DenseNodes(q, row, run, kind, inner, int(dense))


@dataclass(frozen=True)
class DenseLayout:
    """densify.py's dense path before Newton: each node, then its segment's inner points."""

    placed_rad: FloatArray  # (D, n) where each dense point is put
    run: IntArray  # (D,) the run of each
    offset: IntArray  # (N,) dense row of each node
    between: IntArray  # (I,) dense rows of the inner points
    guess_rad: FloatArray  # (I, n) the inner points, on the cubic Hermite curves
    direction: FloatArray  # (I, n) unit directions of those curves there


def dense_layout(
    nodes: DenseNodes,
    tangent: FloatArray,  # (T, n) at the evaluated rows
    found_tangent: FloatArray,  # (L, n) at the refined limit points
) -> DenseLayout:
    """The p-th of a segment's c inner points on the cubic Hermite curve (`hermite`) from
    its node to the next at s = p / (c + 1), the nodes' tangents signed along the chord
    (`along`)."""
    count, n = nodes.q_rad.shape
    total = nodes.dense
    inner = total - count
    rows = len(tangent)
    if np.any(nodes.row >= rows + len(found_tangent)):
        raise ValueError(f"node rows must index the {rows} + {len(found_tangent)} tangents")
    placed, run = np.empty((total, n)), np.empty(total, np.int64)
    offset, between = np.empty(count, np.int64), np.empty(inner, np.int64)
    guess, direction = np.empty((inner, n)), np.empty((inner, n))
    _native.dense_layout(
        nodes.q_rad, nodes.row, nodes.run, nodes.inner, count, n,
        _float64(tangent, "tangent", (rows, n)),
        _float64(found_tangent, "found_tangent", (len(found_tangent), n)), rows,
        placed, run, offset, between, guess, direction,
    )  # fmt: skip
    return DenseLayout(placed, run, offset, between, guess, direction)


def dense_finish(
    nodes: DenseNodes,
    layout: DenseLayout,
    moved_rows: IntArray,  # (M,) dense rows Newton moved: the traced nodes, then inner points
    moved_q_rad: FloatArray,  # (M, n) where Newton left them
    moved_error: FloatArray,  # (M, m) measured there
    evaluated_error: FloatArray,  # (T, m) at the evaluated rows
    found_error: FloatArray,  # (L, m) at the refined limit points
    found_window_rad: FloatArray,  # (L, n) the refined limit points in the window
    runs: int,  # R
    window_low_rad: FloatArray,  # (n,)
    lower_rad: FloatArray,  # (n,)
    upper_rad: FloatArray,  # (n,)
    periodic: BoolArray,  # (n,)
    stray_rad: float,
) -> tuple[FloatArray, FloatArray, IntArray]:  # (P, n), (P, m), (R,)
    """densify.py's dense path after Newton: the moved points and errors in their rows, each
    node's measured error, a limit point at its refined place, a closing repeat left out,
    then `settle_dense`; the points inside, in order, their errors, and how many each run
    keeps."""
    total, n = layout.placed_rad.shape
    count, m = moved_error.shape
    rows = len(evaluated_error)
    found = len(found_error)
    moved_rows = _int64(moved_rows, "moved_rows", (count,))
    if count and (moved_rows.min() < 0 or moved_rows.max() >= total):
        raise ValueError(f"moved_rows must index the {total} dense points")
    nodes_count = len(nodes.row)
    q_out, error_out = np.empty((total, n)), np.empty((total, m))
    run_count = np.empty(runs, np.int64)
    kept = _native.dense_finish(
        layout.placed_rad, total, n, m, _float64(moved_q_rad, "moved_q_rad", (count, n)),
        _float64(moved_error, "moved_error", (count, m)), moved_rows, count, layout.offset,
        nodes.row, nodes.kind, nodes_count,
        _float64(evaluated_error, "evaluated_error", (rows, m)), rows,
        _float64(found_error, "found_error", (found, m)),
        _float64(found_window_rad, "found_window_rad", (found, n)), layout.run, runs,
        *(_float64(v, name, (n,)) for v, name in (
            (window_low_rad, "window_low_rad"), (lower_rad, "lower_rad"),
            (upper_rad, "upper_rad"),
        )),
        np.ascontiguousarray(periodic, dtype=np.uint8), float(stray_rad),
        np.empty((total, n)), np.empty((total, m)), np.empty(nodes_count, np.int64),
        np.empty((nodes_count, n)), np.empty(nodes_count, np.int64),
        np.empty(total, np.uint8), q_out, error_out, run_count,
    )  # fmt: skip
    return q_out[:kept], error_out[:kept], run_count


def closest_strands(
    points_rad: FloatArray,  # (P, n) every curve's points in order, curve after curve
    first: IntArray,  # (C + 1,) curve c is rows first[c] to first[c + 1]
    closed: BoolArray,  # (C,)
    periodic: BoolArray,  # (n,)
    within_rad: float,
    strand_arc_rad: float,
) -> float:
    """The least joint-metric distance, at most `within_rad`, between points of two curves
    or of one curve more than `strand_arc_rad` apart along it (the shorter way round a
    closed one); inf when none (connect/trace/strands.py says what for)."""
    size, n = points_rad.shape
    bounds = _int64(first, "first", (len(first),))
    count = len(bounds) - 1
    if count < 0 or bounds[0] != 0 or bounds[-1] != size or np.any(np.diff(bounds) < 0):
        raise ValueError(f"first must rise from 0 to the {size} points")
    if n > MAX_JOINTS:
        raise ValueError(f"{n} joints; the kernel takes at most {MAX_JOINTS}")
    loops = np.ascontiguousarray(closed, dtype=np.uint8)
    if loops.shape != (count,):
        raise ValueError(f"closed must have one flag per curve ({count}), got {loops.shape}")
    return float(
        _native.closest_strands(
            _float64(points_rad, "points_rad", (size, n)), size, n, bounds, count, loops,
            np.ascontiguousarray(periodic, dtype=np.uint8), float(within_rad),
            float(strand_arc_rad), np.empty(2 * max(size, 1)), np.empty(max(size, 1), np.int64),
            np.empty(size + 2, np.int64),
        )
    )  # fmt: skip


def steps_near_limits(
    start_rad: FloatArray,  # (S, n) unwrapped like its curve
    delta_rad: FloatArray,  # (S, n) to the step's end
    window_low_rad: FloatArray,  # (n,)
    lower_rad: FloatArray,  # (n,)
    upper_rad: FloatArray,  # (n,)
    periodic: BoolArray,  # (n,)
) -> BoolArray:  # (S,)
    """Which trace steps may pass through the joint limits unseen: read in the 2 pi window
    from `window_low_rad`, neither end inside the limits, and the chord passes through the
    limit box widened by a quarter of its length (connect/trace/cut.py)."""
    count, n = start_rad.shape
    split = np.zeros(count, dtype=np.uint8)
    if count:
        _native.steps_near_limits(
            _float64(start_rad, "start_rad", (count, n)),
            _float64(delta_rad, "delta_rad", (count, n)),
            *(_float64(v, name, (n,)) for v, name in (
                (window_low_rad, "window_low_rad"), (lower_rad, "lower_rad"),
                (upper_rad, "upper_rad"),
            )),
            np.ascontiguousarray(periodic, dtype=np.uint8), count, n, split,
        )  # fmt: skip
    return split.astype(bool)


@dataclass(frozen=True)
class _OneDimensionalTask:
    """A task of n - 1 rows on n joints (r = 1: the trace's kernels) as the compiled kernels
    take it: the Jacobian rows read, how many are position rows, the orientation's matrix."""

    rows: IntArray  # (m,)
    m_position: int
    rotation: FloatArray  # (3, 3)
    oriented: bool

    @property
    def m(self) -> int:
        return len(self.rows)

    @classmethod
    def of(
        cls, n: int, position_axes: list[int], target_rotation: OrientationTarget, what: str
    ) -> _OneDimensionalTask:
        orientation_rows, rotation = _orientation(target_rotation)
        rows = np.array([*position_axes, *orientation_rows], dtype=np.int64)
        if not 0 < n <= MAX_JOINTS or len(rows) != n - 1:
            raise ValueError(f"a task of {len(rows)} rows on {n} joints; {what} needs n - 1 rows")
        return cls(rows, len(position_axes), rotation, target_rotation is not None)

    def arguments(self, target_position_m: FloatArray) -> tuple[object, ...]:
        """The kernels' arguments after n: rows, m, m_position, the target position, the
        orientation's matrix and whether there is one."""
        position = _float64(target_position_m, "target_position_m", (self.m_position,))
        return self.rows, self.m, self.m_position, position, self.rotation, self.oriented


@dataclass(frozen=True)
class TraceSteps:
    """Steps of traced curves (C of them), as the refinement near the limits looks at them
    (connect/trace/cut.py's `Steps`)."""

    loop: IntArray  # (C,) which curve
    key: FloatArray  # (C,) where the step starts in the curve: point index (+ fraction)
    span: FloatArray  # (C,) how much of the curve's step it is: 1, 1 / pieces, ...
    start: FloatArray  # (C, n) unwrapped like the curve
    delta: FloatArray  # (C, n) to the step's end, the short way on the torus
    start_tangent: FloatArray  # (C, n) unit, along delta
    end_tangent: FloatArray  # (C, n)


def curve_steps(
    q_rad: FloatArray,  # (E, n) the evaluated points
    tangent: FloatArray,  # (E, n) their unit tangents
    points_rad: FloatArray,  # (P, n) the curves' points, unwrapped along each curve
    rows: IntArray,  # (P,) their rows of q_rad
    first: IntArray,  # (L + 1,) curve l is points [first[l], first[l + 1])
    closed: BoolArray,  # (L,)
) -> TraceSteps:
    """Every step of every curve, the closing step of a closed one included, in curve
    order: cut.py's `Steps.of`, compiled (the same numbers)."""
    count, n = q_rad.shape
    points, curves = len(points_rad), len(closed)
    if n > MAX_JOINTS:
        raise ValueError(f"{n} joints; the kernel takes at most {MAX_JOINTS}")
    bounds = _int64(first, "first", (curves + 1,))
    if bounds[0] != 0 or bounds[-1] != points or np.any(np.diff(bounds) < 0):
        raise ValueError(f"first must run from 0 to the {points} points, never back")
    point_rows = _int64(rows, "rows", (points,))
    if points and (point_rows.min() < 0 or point_rows.max() >= count):
        raise ValueError(f"rows must index the {count} evaluated points")
    loop, key, span = np.empty(points, dtype=np.int64), np.empty(points), np.empty(points)
    start, delta = np.empty((points, n)), np.empty((points, n))
    start_tangent, end_tangent = np.empty((points, n)), np.empty((points, n))
    steps = _native.curve_steps(
        _float64(q_rad, "q_rad", (count, n)), _float64(tangent, "tangent", (count, n)), n,
        _float64(points_rad, "points_rad", (points, n)), point_rows, bounds,
        np.ascontiguousarray(closed, dtype=np.uint8), curves, loop, key, span, start, delta,
        start_tangent, end_tangent,
    )  # fmt: skip
    return TraceSteps(
        loop[:steps], key[:steps], span[:steps], start[:steps], delta[:steps],
        start_tangent[:steps], end_tangent[:steps],
    )  # fmt: skip


@dataclass(frozen=True)
class RefinedRound:
    """One round of the refinement near the limits: the steps it found near them, the
    points it added (A = (pieces - 1) x the steps it split, in order, step after step),
    each with its curve and place, and the pieces of the split steps (the next round's)."""

    near: int  # steps near the limits (0: the refinement is over)
    q_rad: FloatArray  # (A, n)
    error: FloatArray  # (A, m)
    jacobian: FloatArray  # (A, m, n)
    tangent: FloatArray  # (A, n) unit
    loop: IntArray  # (A,) the curve of each
    key: FloatArray  # (A,) its place in the curve: its step's key + span x fraction
    steps: TraceSteps  # (pieces x split steps) the pieces


def refine_round(
    fixed: FloatArray,  # (n, 4, 4) as `chain_kinematics`
    tip: FloatArray,  # (4, 4)
    position_axes: list[int],
    target_position_m: FloatArray,  # (len(position_axes),)
    target_rotation: OrientationTarget,  # as `task_residual`
    steps: TraceSteps,
    window_low_rad: FloatArray,  # (n,)
    lower_rad: FloatArray,  # (n,)
    upper_rad: FloatArray,  # (n,)
    periodic: BoolArray,  # (n,)
    pieces: int,
    iterations: int,
    until: float,
    damping: float,
) -> RefinedRound:
    """One round of cut.py's `refine_near_limits`, compiled (the same numbers): each step
    near the limits (`steps_near_limits`) split at the fractions i / pieces of the Hermite
    curve through its ends, each guess put on the fibre by `iterations` bordered Newton
    steps (`newton`, rows stopping within `until`); a step whose points all reach |e| <
    1e-6 gives its points (with their unit tangents) and its pieces."""
    n = len(fixed)
    task = _OneDimensionalTask.of(n, position_axes, target_rotation, "the refinement")
    m = task.m
    if not 1 < pieces <= 65:
        raise ValueError(f"pieces must be 2 to 65, got {pieces}")
    count, k = len(steps.loop), pieces - 1
    added, split = k * count, pieces * count
    out = TraceSteps(
        np.empty(split, dtype=np.int64), np.empty(split), np.empty(split),
        np.empty((split, n)), np.empty((split, n)), np.empty((split, n)), np.empty((split, n)),
    )  # fmt: skip
    q, error, jacobian = np.empty((added, n)), np.empty((added, m)), np.empty((added, m, n))
    tangent, loop, key = np.empty((added, n)), np.empty(added, dtype=np.int64), np.empty(added)
    scratch = np.empty(k * (2 * n + m + m * n) + n * n + 2 * n + (m + 3) * n)
    vector = (
        (window_low_rad, "window_low_rad"), (lower_rad, "lower_rad"), (upper_rad, "upper_rad"),
    )  # fmt: skip
    near, done = _native.refine_round(
        _float64(fixed, "fixed", (n, 4, 4)), _float64(tip, "tip", (4, 4)), n,
        *task.arguments(target_position_m), count, _int64(steps.loop, "loop", (count,)),
        _float64(steps.key, "key", (count,)), _float64(steps.span, "span", (count,)),
        _float64(steps.start, "start", (count, n)), _float64(steps.delta, "delta", (count, n)),
        _float64(steps.start_tangent, "start_tangent", (count, n)),
        _float64(steps.end_tangent, "end_tangent", (count, n)),
        *(_float64(v, name, (n,)) for v, name in vector),
        np.ascontiguousarray(periodic, dtype=np.uint8), pieces, iterations, float(until),
        float(damping), q, error, jacobian, tangent, loop, key, out.loop, out.key, out.span,
        out.start, out.delta, out.start_tangent, out.end_tangent, scratch,
    )  # fmt: skip
    a, s = k * done, pieces * done
    return RefinedRound(
        near=near, q_rad=q[:a], error=error[:a], jacobian=jacobian[:a], tangent=tangent[:a],
        loop=loop[:a], key=key[:a],
        steps=TraceSteps(
            out.loop[:s], out.key[:s], out.span[:s], out.start[:s], out.delta[:s],
            out.start_tangent[:s], out.end_tangent[:s],
        ),
    )  # fmt: skip


@dataclass(frozen=True)
class LimitPoints:
    """Run ends refined onto the joint limit each curve crosses (E of them)."""

    q_window_rad: FloatArray  # (E, n) in the 2 pi window, the limited joint on its limit
    q_rad: FloatArray  # (E, n) the same in the inner points' unwrapped coordinates
    error: FloatArray  # (E, m)
    jacobian: FloatArray  # (E, m, n)
    tangent: FloatArray  # (E, n) unit, along b - a
    good: BoolArray  # (E,) inside the limits, near a, on the fibre


def limit_points(
    fixed: FloatArray,  # (n, 4, 4) as `chain_kinematics`
    tip: FloatArray,  # (4, 4)
    position_axes: list[int],
    target_position_m: FloatArray,  # (len(position_axes),)
    target_rotation: OrientationTarget,  # as `task_residual`
    a_rad: FloatArray,  # (E, n) each run end's inner point, unwrapped
    b_rad: FloatArray,  # (E, n) the outside point after it
    window_low_rad: FloatArray,  # (n,)
    lower_rad: FloatArray,  # (n,)
    upper_rad: FloatArray,  # (n,)
    periodic: BoolArray,  # (n,)
    iterations: int,
    until: float,
    damping: float,
) -> LimitPoints:
    """densify.py's `limit_points` on a serial chain, compiled (the same numbers): the joint
    that leaves first between a and b set on its limit and held while `iterations` DLS
    steps (rows within `until` stop) put the others back on the fibre."""
    n = len(fixed)
    task = _OneDimensionalTask.of(n, position_axes, target_rotation, "limit points")
    m = task.m
    count = len(a_rad)
    out = LimitPoints(
        np.empty((count, n)), np.empty((count, n)), np.empty((count, m)),
        np.empty((count, m, n)), np.empty((count, n)), np.empty(count, dtype=bool),
    )  # fmt: skip
    vector = (
        (window_low_rad, "window_low_rad"), (lower_rad, "lower_rad"), (upper_rad, "upper_rad"),
    )  # fmt: skip
    if count:
        _native.limit_points(
            _float64(fixed, "fixed", (n, 4, 4)), _float64(tip, "tip", (4, 4)), n,
            *task.arguments(target_position_m), count, _float64(a_rad, "a_rad", (count, n)),
            _float64(b_rad, "b_rad", (count, n)), *(_float64(v, name, (n,)) for v, name in vector),
            np.ascontiguousarray(periodic, dtype=np.uint8), iterations, float(until),
            float(damping), out.q_window_rad, out.q_rad, out.error, out.jacobian, out.tangent,
            out.good.view(np.uint8), np.empty(n * n + 5 * n + (m + 3) * n),
        )  # fmt: skip
    return out


def nearest_points(
    points_rad: FloatArray,  # (P, n)
    queries_rad: FloatArray,  # (K, n)
    periodic: BoolArray,  # (n,)
    k: int,
    reach_rad: float = np.inf,
) -> IntArray:  # (K, k) rows of points_rad, nearest first; -1 past the last one found
    """Each query's k nearest points within `reach_rad` (joint metric, wrapped on the
    periodic joints), nearest first, the lower row first among equally near, from a grid
    on two joints (what a KD-tree over the joint box answers, without its build: 0.41 ms
    over an iiwa14 pose answer's 1700 path points)."""
    size, n = points_rad.shape
    count = len(queries_rad)
    if n > MAX_JOINTS or not 1 <= k <= MAX_JOINTS:
        raise ValueError(f"{n} joints and k = {k}; the kernel takes at most {MAX_JOINTS} of each")
    out = np.full((count, k), -1, dtype=np.int64)
    if count and size:
        _native.nearest_points(
            _float64(points_rad, "points_rad", (size, n)), size,
            _float64(queries_rad, "queries_rad", (count, n)), count,
            np.ascontiguousarray(periodic, dtype=np.uint8), n, k, float(reach_rad), out,
        )  # fmt: skip
    return out


def spread_seeds(q_rad: FloatArray, spacing_rad: float) -> IntArray:  # (M, n) -> (S,)
    """The rows of a subset of q_rad, greedily at least `spacing_rad` apart on the joint
    torus (every joint a circle): in order, each row not within the spacing of a row
    already chosen is chosen."""
    count, n = q_rad.shape
    chosen = np.empty(count, dtype=np.int64)
    found = 0
    if count:
        found = _native.spread_seeds(
            _float64(q_rad, "q_rad", (count, n)), count, n, float(spacing_rad), chosen
        )
    return chosen[:found]


# Nodes whose nearest node of every set are tabled at once: the table is rows x sets,
# and a 4-D fibre of 10,000 samples can hold thousands of components of several nodes.
SETS_BLOCK_ROWS = 256


def nearest_of_sets(
    points: FloatArray,  # (N, n) KD-tree box coordinates
    box: FloatArray,  # (n,) a finite width makes its dimension periodic with it
    set_of: IntArray,  # (N,) each node's set in [0, M), -1 for a node in none
    sets: int,  # M
    radius: float,
    threads: int = 1,
) -> tuple[IntArray, IntArray, FloatArray]:  # (F,) node of the set, (F,) node x, (F,) length
    """For each node x and each set m that x is not in, the nearest node of m within
    `radius` (strictly; the lower row among equally near), as links in order of the set,
    then of x. By brute force, SETS_BLOCK_ROWS nodes at a time, their rows split over
    `threads`: what one KD-tree per set, queried by every node, answers."""
    count, n = points.shape
    members = _int64(set_of, "set_of", (count,))
    if count and (members.min() < -1 or members.max() >= sets):
        raise ValueError(f"set_of must be -1 or a set in [0, {sets})")
    none = np.zeros(0, dtype=np.int64)
    if not (count and sets):
        return none, none, np.zeros(0)
    coordinates, widths = _float64(points, "points", (count, n)), _float64(box, "box", (n,))
    member = np.argsort(members, kind="stable")  # (N,) set after set, rows ascending in each
    member = member[members[member] >= 0]
    start = np.searchsorted(members[member], np.arange(sets + 1)).astype(np.int64)  # (M + 1,)
    grouped = np.ascontiguousarray(coordinates[member])
    found: list[tuple[IntArray, IntArray, IntArray, FloatArray]] = []  # (set, x, y, length)
    for first in range(0, count, SETS_BLOCK_ROWS):
        size = min(SETS_BLOCK_ROWS, count - first)
        best = np.empty((size, sets), dtype=np.int64)
        distance = np.empty((size, sets))

        _native.nearest_of_sets(
            coordinates, n, widths, members, grouped, member, start, sets, float(radius),
            first, first + size, best, distance, helper_rows(size, threads),
        )  # fmt: skip
        x, m = np.nonzero(best >= 0)
        found.append((m, first + x, best[x, m], distance[x, m]))
    set_index, x, y, length = (np.concatenate(column) for column in zip(*found, strict=True))
    order = np.lexsort((x, set_index))  # by set, then node
    return y[order], x[order], length[order]


def links_within(
    points: FloatArray,  # (N, n) KD-tree box coordinates
    box: FloatArray,  # (n,) a finite width makes its dimension periodic with it
    rows: IntArray,  # (R,) nodes whose links are wanted
    radius: float,
) -> tuple[IntArray, IntArray, FloatArray]:  # (L,) index into rows, (L,) node, (L,) length
    """Every node within `radius` (strictly) of each of `rows`, itself excepted, in order
    of `rows` then node: what a sparse distance matrix of their KD-trees lists."""
    count, n = points.shape
    asked = _int64(rows, "rows", (len(rows),))
    if len(asked) and (asked.min() < 0 or asked.max() >= count):
        raise ValueError(f"rows must index the {count} points")
    arguments = (
        _float64(points, "points", (count, n)), count, n, _float64(box, "box", (n,)), asked,
        len(asked), float(radius),
    )  # fmt: skip
    none = np.empty(0, dtype=np.int64)
    total = _native.links_within(*arguments, False, none, none, np.empty(0))
    i, y, length = np.empty(total, np.int64), np.empty(total, np.int64), np.empty(total)
    if total:
        _native.links_within(*arguments, True, i, y, length)
    return i, y, length


def merge_labels(
    labels: IntArray,  # (N,) each node's part, in [0, L)
    a: IntArray,  # (E,) parts joined by an edge ...
    b: IntArray,  # (E,) ... to these
) -> IntArray:  # (N,)
    """The parts merged along the edges, numbered 0, 1, ... in the order of their lowest
    node (as scipy's connected_components numbers components): union-find over the parts."""
    count = len(labels)
    parts = _int64(labels, "labels", (count,))
    joined = (_int64(a, "a", (len(a),)), _int64(b, "b", (len(b),)))
    if len(joined[0]) != len(joined[1]):
        raise ValueError(f"a and b must be as long, got {len(joined[0])} and {len(joined[1])}")
    size = int(max(parts.max(initial=-1), *(e.max(initial=-1) for e in joined))) + 1
    if min(parts.min(initial=0), *(e.min(initial=0) for e in joined)) < 0:
        raise ValueError("labels and edge ends must be >= 0")
    out = np.empty(count, dtype=np.int64)
    _native.merge_labels(
        parts, count, size, *joined, len(joined[0]), out, np.empty(max(size, 1), np.int64),
        np.empty(max(size, 1), np.int64),
    )  # fmt: skip
    return out
