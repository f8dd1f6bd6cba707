"""The frame of every chain joint at a configuration: where the robot's bodies are.

chain.json (`ChainSpec`) gives, per joint k, the fixed transform from the previous joint's
frame and the unit axis; joint k's frame at q is

    T_k(q) = origin_1 Rot(axis_1, q_1) ... origin_k Rot(axis_k, q_k),   T_0 = identity,

the URDF frame of joint k's child link, the frame its collision bodies (and those fixed to
it) are given in (`CollisionBody.frame`). Rot(axis, q) by Rodrigues' formula.
"""

from __future__ import annotations

import numpy as np

from service.manifest import ChainSpec
from service.pipeline import native
from service.pipeline.arrays import FloatArray


def chain_frames(chain: ChainSpec, q_rad: FloatArray) -> FloatArray:  # (B, n + 1, 4, 4)
    """T_0 .. T_n for each configuration q_rad (B, n): rotation block and origin in the
    base frame, metres (compiled: `native.chain_frames`)."""
    return frames_of(*joint_transforms(chain), q_rad)


def joint_transforms(chain: ChainSpec) -> tuple[FloatArray, FloatArray]:
    """Each joint's fixed transform (n, 4, 4) and unit axis (n, 3), as arrays: what
    `frames_of` takes (a caller that places bodies often keeps them)."""
    origin = np.array([joint.origin for joint in chain.joints], dtype=np.float64)
    axis = np.array([joint.axis for joint in chain.joints], dtype=np.float64)
    return origin, axis


def frames_of(
    origin: FloatArray,  # (n, 4, 4)
    axis: FloatArray,  # (n, 3)
    q_rad: FloatArray,  # (B, n)
) -> FloatArray:  # (B, n + 1, 4, 4)
    """`chain_frames` from the chain's joint transforms already as arrays."""
    q = np.asarray(q_rad, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != len(origin):
        raise ValueError(f"joint values have shape {q.shape}; expected (B, {len(origin)})")
    return native.chain_frames(origin, axis, q)
