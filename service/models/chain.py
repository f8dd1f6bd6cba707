"""Forward kinematics and geometric Jacobian of a serial chain, batched numpy, from chain.json.

The same answer as kinematics.onnx (the chain's FK and Jacobian exported from
pytorch-kinematics): q (B, n) float64 -> position (B, 3), rotation (B, 3, 3) and the
geometric Jacobian (B, 6, n), base frame, linear rows first (J_v = z_i x (p_ee - p_i),
J_w = z_i for revolute joint i with world axis z_i through p_i). Both come from the same
URDF chain (`training.export` writes chain.json beside kinematics.onnx and checks both
against pytorch-kinematics); the registry checks this kernel against kinematics.onnx at
load and refuses the model if they differ.

Construction folds everything constant. chain.json gives per joint the fixed transform
from the previous joint's frame (fixed joints already folded in) and a unit axis. A
constant rotation Q_i with Q_i e_z = axis_i turns the joint into a rotation about its
frame's z axis, Rot(axis_i, q) = Q_i Rz(q) Q_i^T, and Q_i^T is folded into the next
joint's fixed transform (or the tip's); for the usual z axes Q_i is exactly the
identity. Per call and per joint that leaves one constant product, done for the whole
batch as one (4, 4) x (4, 3B) matrix product (the frame's columns rotated, and its origin
moved, into the next joint's frame), and Rz(q), which only mixes the frame's first two
columns: c x + s y and c y - s x on contiguous (3, B) rows, no 3x3 built per joint.
The frames are held batch-last, `frames[i] = [x_i; y_i; z_i; p_i]` (4, 3, B), so z_i and
p_i of every joint stay in place for the Jacobian.

A non-finite joint value gives non-finite outputs in its own row only (every operation
acts on one batch column at a time), without a warning.

Measured by `python -m tools.kinematics_bench` (iiwa14, 7 joints; lscpu: AMD EPYC, family
25 model 17, 2 cores, load 1.3; one thread; both in turn, median of 40 rounds), the same
run, time per call (per configuration):

    batch    chain.json (this kernel)    kinematics.onnx (one onnxruntime thread)
        1       62 us                        98 us
       30       73 us  (2.4 us)             302 us  (10.1 us)
      200      104 us  (0.52 us)            1.43 ms (7.2 us)
     1000      242 us  (0.24 us)            7.09 ms (7.1 us)
    10000      2.75 ms (0.28 us)            93.5 ms (9.4 us)

and the two agree to 1.2e-15 over 10,000 configurations. The iiwa14 pose's connect stage
(`tools/connect_profile`, 8 targets, ~37 calls and ~4,600 configurations each) took a
median 22 ms (p95 32 ms) with it against 57 ms (p95 85 ms) with kinematics.onnx, its
kinematics 4.5 ms against 37 ms.
"""

from __future__ import annotations

import math
import queue
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from service.errors import ModelVerificationError
from service.manifest import ChainSpec
from service.pipeline.arrays import FloatArray
from service.pipeline.types import KinematicsResult

# Configurations per pass. A pass costs ~55 us of numpy calls plus ~0.17 us per
# configuration (iiwa14, this machine), so at 4096 the calls are under a tenth of it. Its
# workspace, 26 n + 18 doubles per configuration (6.5 MB for the iiwa14 at 4096), is kept
# for the next call: fresh temporaries cost page faults that took a 1000-configuration
# call from 0.25 to 0.95 ms here.
CHUNK = 4096


def _z_to_axis(axis: FloatArray) -> FloatArray:  # axis (3,) unit -> (3, 3)
    """A rotation Q with Q e_z = axis; exactly the identity for +z and diag(1, -1, -1) for -z."""
    if axis[0] == 0.0 and axis[1] == 0.0:
        return np.diag([1.0, 1.0, 1.0]) if axis[2] > 0 else np.diag([1.0, -1.0, -1.0])
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    x = np.cross(helper, axis)
    x /= np.linalg.norm(x)
    y = np.cross(axis, x)
    return np.column_stack([x, y, axis])


class SerialChainKinematics:
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

    @classmethod
    def from_file(cls, path: Path) -> SerialChainKinematics:
        """Read and validate chain.json; ModelVerificationError naming the file if it is not one."""
        try:
            return cls(ChainSpec.model_validate_json(path.read_bytes()))
        except (OSError, ValidationError) as error:
            raise ModelVerificationError(f"{path}: unreadable chain: {error}") from error

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
