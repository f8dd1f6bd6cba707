"""The frame of every chain joint at a configuration: where the robot's bodies are.

chain.json (`ChainSpec`) gives, per joint k, the fixed transform from the previous joint's
frame and the unit axis; joint k's frame at q is

    T_k(q) = origin_1 Rot(axis_1, q_1) ... origin_k Rot(axis_k, q_k),   T_0 = identity,

the URDF frame of joint k's child link, the frame its collision bodies (and those fixed to
it) are given in (`CollisionBody.frame`). Rot(axis, q) by Rodrigues' formula, the whole
batch at once.
"""

from __future__ import annotations

import numpy as np

from service.manifest import ChainSpec
from service.pipeline.arrays import FloatArray


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
