"""The numpy kernels the compiled ones (service/pipeline/native.c) replaced, kept as the
reference they are pinned to (tests/service/pipeline/test_native.py): the serial chain's
FK and Jacobian (batch-last frames, cos and sin from tan(q / 2)), and the DLS step by
LAPACK's batched solve; every URDF joint frame (Rodrigues' formula on whole columns),
the least sphere gap of self-collision (two passes over padded arrays), the distance
from samples to the path segments beside their nearest path points, and the trace's
tangent signs, cubic Hermite guesses, choice of the steps to refine near the limits and
last pass over its dense points.
"""

from __future__ import annotations

import math
import queue

import numpy as np

from service.manifest import ChainSpec
from service.models.chain import SerialChainKinematics, _z_to_axis
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.collision.robot import PlacedBodies, RobotSpheres
from service.pipeline.joint_space import joint_difference, wrap_to_pi
from service.pipeline.types import KinematicsResult

CHUNK = 4096


class NumpyChainKinematics:
    """The `Kinematics` Protocol on a serial chain of revolute joints: pure batched numpy."""

    def __init__(self, spec: ChainSpec) -> None:
        self.spec = spec
        self.joint_count = len(spec.joints)
        # Per joint i, A_i = Q_{i-1}^T origin_i Q_i (no Q_{i-1} for the first): its fixed
        # transform with the axis alignments folded in on both sides. Kept transposed: with
        # the previous frame as rows [x; y; z; p] (4, 3B), its rotation's columns and its
        # origin, A^T = [[R^T, 0], [t^T, 1]] times them gives the columns of (its rotation) R
        # and p + (its rotation) t: joint i's frame before q_i turns it.
        carry = np.eye(4)
        transposed = []
        for joint in spec.joints:
            align = np.eye(4)
            align[:3, :3] = _z_to_axis(np.asarray(joint.axis, dtype=np.float64))
            fixed = carry @ np.asarray(joint.origin, dtype=np.float64) @ align
            transposed.append(np.ascontiguousarray(fixed.T))
            carry = align.T
        self._fixed_t = np.stack(transposed)  # (n, 4, 4)
        self._tip_t = np.ascontiguousarray((carry @ np.asarray(spec.tip, dtype=np.float64)).T)
        # Scratch memory of calls that have returned, for the next ones: as many as calls
        # have run at once.
        self._workspaces: queue.SimpleQueue[FloatArray] = queue.SimpleQueue()

    def __call__(self, q_rad: FloatArray) -> KinematicsResult:  # q_rad (B, n), float64
        q = np.asarray(q_rad, dtype=np.float64)
        n = self.joint_count
        if q.ndim != 2 or q.shape[1] != n:
            raise ValueError(f"joint values have shape {q.shape}; expected (B, {n})")
        batch = q.shape[0]
        position = np.empty((batch, 3))
        rotation = np.empty((batch, 3, 3))
        jacobian = np.empty((batch, 6, n))
        # A workspace no other call is using, grown to this call's pass if it is smaller.
        try:
            workspace = self._workspaces.get_nowait()
        except queue.Empty:
            workspace = np.empty(0)
        if workspace.size < (size := (26 * n + 18) * min(batch, CHUNK)):
            workspace = np.empty(size)
        try:
            for start in range(0, batch, CHUNK):
                span = slice(start, start + CHUNK)
                self._evaluate(q[span], workspace, position[span], rotation[span], jacobian[span])
        finally:
            self._workspaces.put(workspace)
        return KinematicsResult(position_m=position, rotation=rotation, jacobian=jacobian)

    def _evaluate(
        self,
        q: FloatArray,  # (B, n), B <= CHUNK
        workspace: FloatArray,  # (>= (26 n + 18) B,) scratch
        position: FloatArray,  # (B, 3), written
        rotation: FloatArray,  # (B, 3, 3), written
        jacobian: FloatArray,  # (B, 6, n), written
    ) -> None:
        n, batch = self.joint_count, q.shape[0]
        t, cos, signed_sin, frames, turned, end, lever, rows, product = _carve(
            workspace,
            (n, batch), (n, batch), (n, 2, 1, batch), (n, 4, 3, batch), (2, 3, batch),
            (4, 3, batch), (n, 3, batch), (6, n, batch), (n, batch),
        )  # fmt: skip
        # cos and sin from the half-angle tangent: numpy's float64 tan is vectorised, its
        # sin and cos are not (here 2.3 ns a value against 8.4 ns for each of them).
        # t = tan(q/2), d = 2 / (1 + t^2): cos q = d - 1, sin q = t d, to a few 1e-16 for
        # any q (tan of the float nearest pi/2 is finite), NaN for a non-finite q.
        np.multiply(q.T, 0.5, out=t)
        with np.errstate(invalid="ignore"):  # tan(inf) is NaN: that row's answer, no warning
            np.tan(t, out=t)
        np.multiply(t, t, out=cos)
        cos += 1.0
        np.divide(2.0, cos, out=cos)  # d
        np.multiply(t, cos, out=signed_sin[:, 0, 0])
        np.negative(signed_sin[:, 0, 0], out=signed_sin[:, 1, 0])
        cos -= 1.0

        # frames[i] = [x_i; y_i; z_i; p_i] (4, 3, B): the columns of joint i's frame, turned
        # by q_i, in base coordinates, and its origin.
        frames[0] = self._fixed_t[0][:, :3, None]  # A_0^T times the base frame, the identity
        for i in range(n):
            frame = frames[i]
            if i:
                np.matmul(
                    self._fixed_t[i],  # (4, 4)
                    frames[i - 1].reshape(4, 3 * batch),
                    out=frame.reshape(4, 3 * batch),
                )
            # Rz(q_i) on the frame's columns: x <- c x + s y, y <- c y - s x.
            np.multiply(signed_sin[i], frame[1::-1], out=turned)  # (2, 3, B): s y, -s x
            frame[:2] *= cos[i]
            frame[:2] += turned
        np.matmul(self._tip_t, frames[n - 1].reshape(4, 3 * batch), out=end.reshape(4, 3 * batch))

        # Jacobian rows (6, n, B): z_i x (p_ee - p_i), then z_i.
        z = frames[:, 2]  # (n, 3, B): joint axes in base coordinates
        np.subtract(end[3], frames[:, 3], out=lever)  # (n, 3, B): p_ee - p_i
        for row, (a, b) in enumerate(((1, 2), (2, 0), (0, 1))):
            np.multiply(z[:, a], lever[:, b], out=rows[row])
            np.multiply(z[:, b], lever[:, a], out=product)
            rows[row] -= product
        rows[3:] = z.transpose(1, 0, 2)
        jacobian[...] = rows.transpose(2, 0, 1)
        position[...] = end[3].T
        rotation[...] = end[:3].transpose(2, 1, 0)


def _carve(workspace: FloatArray, *shapes: tuple[int, ...]) -> list[FloatArray]:
    """Consecutive contiguous arrays of these shapes at the start of `workspace`."""
    arrays, offset = [], 0
    for shape in shapes:
        size = math.prod(shape)
        arrays.append(workspace[offset : offset + size].reshape(shape))
        offset += size
    return arrays


def dls_step(
    jacobian: FloatArray,  # (B, m, n)
    error: FloatArray,  # (B, m)
    damping: float,
) -> FloatArray:  # (B, n)
    """One damped-least-squares step dq = J^T (J J^T + damping^2 I)^-1 e.

    Failures stay in their own rows: a row whose Jacobian or error is not finite gets a
    NaN step (its sample is then rejected), and a singular system (zero damping at a
    kinematic singularity) falls back to the pseudo-inverse instead of failing the batch.
    """
    batch, m, n = jacobian.shape
    # A row is finite where its sums are: any NaN or infinity in it makes them non-finite
    # (the entries are bounded by the arm's reach, so a finite row's sum does not overflow).
    # This is a fifth of the time of an elementwise check over (B, m, n).
    with np.errstate(invalid="ignore"):  # inf - inf is NaN: that row is not finite
        finite = np.isfinite(jacobian.sum(axis=(1, 2)) + error.sum(axis=1))  # (B,)
    every = bool(finite.all())
    if not every and not finite.any():
        return np.full((batch, n), np.nan)
    # Every row finite (the usual case): the arrays as they are, no copies.
    j, e = (jacobian, error) if every else (jacobian[finite], error[finite])  # (B', m, n), (B', m)
    jacobian_t = np.swapaxes(j, 1, 2)  # (B', n, m)
    gram = j @ jacobian_t  # (B', m, m)
    gram.reshape(len(j), m * m)[:, :: m + 1] += damping * damping  # + damping^2 I, in place
    try:
        y = np.linalg.solve(gram, e[..., None])  # (B', m, 1)
    except np.linalg.LinAlgError:
        y = np.linalg.pinv(gram) @ e[..., None]
    step = (jacobian_t @ y)[..., 0]  # (B', n)
    if every:
        return step
    dq = np.full((batch, n), np.nan)
    dq[finite] = step
    return dq


def chain_frames(chain: ChainSpec, q_rad: FloatArray) -> FloatArray:  # (B, n + 1, 4, 4)
    """T_0 .. T_n for each configuration q_rad (B, n): rotation block and origin in the
    base frame, metres."""
    q = np.asarray(q_rad, dtype=np.float64)
    batch, n = q.shape
    if n != len(chain.joints):
        raise ValueError(f"joint values have shape {q.shape}; expected (B, {len(chain.joints)})")
    frames = np.empty((batch, n + 1, 4, 4))
    frames[:, 0] = np.eye(4)
    cos, sin = np.cos(q), np.sin(q)  # (B, n)
    for k, joint in enumerate(chain.joints):
        axis = np.asarray(joint.axis, dtype=np.float64)  # (3,)
        cross = np.array(
            [[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]]
        )
        outer = np.outer(axis, axis)
        # Rot = cos I + sin [a]x + (1 - cos) a a^T  (B, 3, 3)
        rotation = (
            cos[:, k, None, None] * np.eye(3)
            + sin[:, k, None, None] * cross
            + (1.0 - cos[:, k, None, None]) * outer
        )
        fixed = frames[:, k] @ np.asarray(joint.origin, dtype=np.float64)  # (B, 4, 4)
        frames[:, k + 1] = fixed
        frames[:, k + 1, :3, :3] = fixed[:, :3, :3] @ rotation
    return frames


def self_clearance_m(self: RobotSpheres, placed: PlacedBodies) -> FloatArray:  # -> (B,)
    """The least |c_a - c_b| - r_a - r_b over the sphere pairs of the checked body
    pairs (negative: overlapping); +inf when no pair is checked."""
    batch = len(placed.bound_centres_m)
    if not len(self.pair_a):
        return np.full(batch, np.inf)
    a, b = self.pair_a, self.pair_b
    bounds = placed.bound_centres_m
    lower = np.linalg.norm(bounds[:, a] - bounds[:, b], axis=2)  # (B, P)
    lower -= self.bound_radius_m[a] + self.bound_radius_m[b]
    first = placed.first_centres_m  # (B, K, 3): one sphere per body
    upper = np.linalg.norm(first[:, a] - first[:, b], axis=2)
    upper -= self.radius_m[a, 0] + self.radius_m[b, 0]  # (B, P)
    clearance = upper.min(axis=1)  # (B,) attained by a sphere pair
    rows, pairs = np.nonzero(lower < clearance[:, None])  # (N,), (N,)
    if len(rows):
        ca = placed.spheres(rows, a[pairs])  # (N, S, 3)
        cb = placed.spheres(rows, b[pairs])
        gap = np.linalg.norm(ca[:, :, None] - cb[:, None], axis=3)  # (N, S, S)
        gap -= self.radius_m[a[pairs]][:, :, None] + self.radius_m[b[pairs]][:, None]
        np.minimum.at(clearance, rows, gap.min(axis=(1, 2)))
    return clearance


class NumpyStepsKinematics:
    """The chain's kinematics behind a plain callable: not a ChainKinematics, so a fibre
    on it takes the numpy steps (`correction.iterate`, the trace's numpy walk) that the
    compiled ones are pinned to."""

    def __init__(self, kinematics: SerialChainKinematics) -> None:
        self.kinematics = kinematics

    def __call__(self, q_rad: np.ndarray) -> KinematicsResult:
        return self.kinematics(q_rad)


def nearest_segment(
    q_rad: FloatArray,  # (K, n)
    points_rad: FloatArray,  # (P, n)
    before: IntArray,  # (P,)
    after: IntArray,  # (P,)
    nearest: IntArray,  # (K, k)
    periodic: BoolArray,  # (n,)
) -> tuple[FloatArray, IntArray]:  # (K,) least distance, (K,) the candidate point reaching it
    """The least distance from each q to the segments candidate-before and candidate-after."""
    a = points_rad[nearest]  # (K, k, n)
    distance = np.minimum(
        segment_distance(q_rad, a, points_rad[before[nearest]], periodic),
        segment_distance(q_rad, a, points_rad[after[nearest]], periodic),
    )  # (K, k)
    best = np.argmin(distance, axis=1)
    rows = np.arange(len(q_rad))
    return distance[rows, best], nearest[rows, best]


def segment_distance(
    q_rad: FloatArray,  # (K, n)
    a_rad: FloatArray,  # (K, k, n) segment starts
    b_rad: FloatArray,  # (K, k, n) segment ends
    periodic: BoolArray,
) -> FloatArray:  # (K, k) joint-metric distance from each q to each segment a-b
    along = joint_difference(b_rad, a_rad, periodic)  # (K, k, n)
    offset = joint_difference(q_rad[:, None, :], a_rad, periodic)
    length2 = np.einsum("kcn,kcn->kc", along, along)
    fraction = np.clip(
        np.einsum("kcn,kcn->kc", offset, along) / np.maximum(length2, 1e-300), 0.0, 1.0
    )
    return np.linalg.norm(offset - fraction[..., None] * along, axis=2)


def along(tangent: FloatArray, direction: FloatArray) -> FloatArray:  # (K, n) -> (K, n)
    """Each tangent with the sign that points it along `direction`; where the tangent is
    not finite (a rank-deficient Jacobian), the unit direction itself."""
    if not np.isfinite(tangent).all():
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = direction / np.linalg.norm(direction, axis=1, keepdims=True)
        tangent = np.where(np.all(np.isfinite(tangent), axis=1, keepdims=True), tangent, unit)
    return np.where(np.einsum("kn,kn->k", tangent, direction)[:, None] < 0.0, -tangent, tangent)


def hermite(
    p0: FloatArray,  # (K, n)
    t0: FloatArray,  # (K, n) unit tangent at p0, pointing toward p1
    p1: FloatArray,  # (K, n)
    t1: FloatArray,  # (K, n) unit tangent at p1, pointing away from p0
    s: FloatArray,  # (K,) in [0, 1]
) -> tuple[FloatArray, FloatArray]:  # (K, n) points, (K, n) unit directions of the curve
    """The cubic Hermite curve from p0 to p1 with end tangents t0, t1 scaled by the chord
    length, at parameter s: off a smooth curve by O(L^4) where the chord is off by O(L^2)."""
    chord = p1 - p0  # (K, n)
    length = np.linalg.norm(chord, axis=1, keepdims=True)  # (K, 1)
    s = s[:, None]
    r = 1.0 - s
    point = (
        p0
        + (s * s * (3.0 - 2.0 * s)) * chord
        + (length * s * r * r) * t0
        - (length * s * s * r) * t1
    )
    direction = (
        (6.0 * s * r) * chord
        + (length * r * (1.0 - 3.0 * s)) * t0
        + (length * s * (3.0 * s - 2.0)) * t1
    )
    with np.errstate(invalid="ignore"):
        direction = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    return point, direction


def settle_dense(
    q_rad: FloatArray,
    placed_rad: FloatArray,
    window_low_rad: FloatArray,
    lower_rad: FloatArray,
    upper_rad: FloatArray,
    periodic: BoolArray,
    stray_rad: float,
    fixed_rows: IntArray,
    fixed_rad: FloatArray,
    excluded_rows: IntArray,
) -> tuple[FloatArray, BoolArray]:
    """densify.py's last pass as numpy steps (native.settle_dense)."""
    strayed = np.linalg.norm(q_rad - placed_rad, axis=1) > stray_rad
    q = window_low_rad + np.mod(q_rad - window_low_rad, 2.0 * np.pi)
    q[fixed_rows] = fixed_rad
    inside = np.all(periodic | ((q >= lower_rad) & (q <= upper_rad)), axis=1) & ~strayed
    inside[excluded_rows] = False
    return np.where(periodic, wrap_to_pi(q), q), inside


def chord_meets_box(
    a: FloatArray, b: FloatArray, lower: FloatArray, upper: FloatArray, periodic: BoolArray
) -> BoolArray:  # (S,)
    """Whether each segment a -> b (S, n) passes through the box (slab test, limited joints)."""
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lower - a) / d
        t2 = (upper - a) / d
    entry = np.where(
        d == 0, np.where((a >= lower) & (a <= upper), -np.inf, np.inf), np.minimum(t1, t2)
    )
    leave = np.where(
        d == 0, np.where((a >= lower) & (a <= upper), np.inf, -np.inf), np.maximum(t1, t2)
    )
    entry = np.where(periodic, -np.inf, entry).max(axis=1)
    leave = np.where(periodic, np.inf, leave).min(axis=1)
    return (entry <= leave) & (leave >= 0.0) & (entry <= 1.0)


def steps_near_limits(
    start_rad: FloatArray,
    delta_rad: FloatArray,
    window_low_rad: FloatArray,
    lower_rad: FloatArray,
    upper_rad: FloatArray,
    periodic: BoolArray,
) -> BoolArray:
    """cut.py's choice of the steps to split as numpy steps (native.steps_near_limits)."""
    a = window_low_rad + np.mod(start_rad - window_low_rad, 2.0 * np.pi)
    b = a + delta_rad
    inside = [np.all(periodic | ((x >= lower_rad) & (x <= upper_rad)), axis=1) for x in (a, b)]
    margin = 0.25 * np.linalg.norm(delta_rad, axis=1, keepdims=True)
    meets = chord_meets_box(a, b, lower_rad - margin, upper_rad + margin, periodic)
    return meets & ~inside[0] & ~inside[1]
