"""Stage 2: sample configurations by integrating the learned velocity field from t=0 to 1.

q_0 ~ N(0, I) in normalised joint coordinates; explicit Euler,
q_{k+1} = q_k + dt * v(q_k, t_k, x); then back to radians.
"""

from __future__ import annotations

import numpy as np

from service.manifest import AffineNormalisation
from service.pipeline.arrays import BoolArray, Float32Array, FloatArray
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.joint_space import wrap_periodic
from service.pipeline.types import VelocityField


def euler_integrate(
    velocity: VelocityField,
    q_0: Float32Array,  # (N, n)
    condition: Float32Array,  # (N, c)
    steps: int,
    deadline: Deadline = NO_DEADLINE,
) -> Float32Array:  # (N, n)
    """Integrate dq/dt = v(q, t, x) over t in [0, 1] with `steps` explicit Euler steps."""
    dt = np.float32(1.0 / steps)
    q_t = q_0
    t = np.empty((q_0.shape[0], 1), dtype=np.float32)
    for k in range(steps):
        deadline.check("sample")
        t.fill(k * dt)
        q_t = q_t + dt * velocity(q_t, t, condition)
    return q_t


def sample_configurations(
    velocity: VelocityField,
    condition: Float32Array,  # (c,)
    num_samples: int,
    steps: int,
    joint_normalisation: AffineNormalisation,
    periodic: BoolArray,  # (n,)
    rng: np.random.Generator,
    deadline: Deadline = NO_DEADLINE,
) -> FloatArray:  # (N, n) rad
    """Draw `num_samples` configurations for one target, periodic joints wrapped."""
    n = len(periodic)
    q_0 = rng.standard_normal((num_samples, n), dtype=np.float32)
    conditions = np.broadcast_to(condition, (num_samples, condition.shape[0]))
    q_1 = euler_integrate(velocity, q_0, np.ascontiguousarray(conditions), steps, deadline)
    q_rad = joint_normalisation.denormalise(q_1.astype(np.float64))
    return wrap_periodic(q_rad, periodic)
