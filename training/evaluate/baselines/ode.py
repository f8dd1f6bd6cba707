"""The paper's ODE baseline: trace a 1-D SMM by integrating its null-space tangent.

dq/ds = n(q), the unit null vector of the task Jacobian J(q) (m x n, r = n - m = 1),
its sign kept continuous along the curve. Integrated with the Cash-Karp embedded
Runge-Kutta pair at a fixed step of 0.05 rad (its fifth-order solution), from a start
configuration until the trace comes back within 0.05 rad of it (closure), as in the
paper's "ODE" row. There is no correction: the drift off the fibre is the method's error.
Joint limits are ignored while tracing (the paper traces the unconstrained loop), and
every joint is revolute, so the loop lives on the torus: closure is measured with all
joint differences wrapped (a loop may turn a joint by a full 2 pi before it closes).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from service.manifest import TaskSpec
from service.pipeline.correction import jacobian_on_fibre
from service.pipeline.joint_space import joint_distance, wrap_periodic
from service.pipeline.types import FloatArray, Kinematics

STEP_RAD = 0.05
CLOSURE_RAD = 0.05

# Cash-Karp tableau: nodes' coefficients and the fifth-order weights.
_A = (
    (),
    (1 / 5,),
    (3 / 40, 9 / 40),
    (3 / 10, -9 / 10, 6 / 5),
    (-11 / 54, 5 / 2, -70 / 27, 35 / 27),
    (1631 / 55296, 175 / 512, 575 / 13824, 44275 / 110592, 253 / 4096),
)
_B5 = (37 / 378, 0.0, 250 / 621, 125 / 594, 0.0, 512 / 1771)


def task_jacobian(kinematics: Kinematics, q_rad: FloatArray, task: TaskSpec) -> FloatArray:
    """(m, n) Jacobian of the task's constrained rows at one configuration (n,)."""
    return jacobian_on_fibre(kinematics(q_rad[None]), task)[0]


def null_tangent(jacobian: FloatArray, previous: FloatArray) -> FloatArray:
    """(n,) unit null vector of a rank-(n-1) Jacobian (n-1, n), on the side of `previous`."""
    _, _, v_t = np.linalg.svd(jacobian)  # rows of v_t: right singular vectors
    tangent = v_t[-1]
    return tangent if tangent @ previous >= 0 else -tangent


@dataclass(frozen=True)
class Trace:
    q_rad: FloatArray  # (K, n) points along the curve, the start first
    closed: bool  # came back within CLOSURE_RAD of the start
    length_rad: float
    wall_time_ms: float


def trace_smm(
    kinematics: Kinematics,
    task: TaskSpec,
    q_start_rad: FloatArray,  # (n,) a configuration on the SMM
    max_length_rad: float = 200.0,
) -> Trace:
    """Trace the SMM loop through `q_start_rad` with fixed-step Cash-Karp RK5."""
    start = time.perf_counter()
    torus = np.ones(len(q_start_rad), dtype=bool)  # every joint revolute
    jacobian = task_jacobian(kinematics, q_start_rad, task)
    if jacobian.shape[0] != jacobian.shape[1] - 1:
        raise ValueError(
            f"the ODE baseline traces 1-D SMMs only; this task leaves r = "
            f"{jacobian.shape[1] - jacobian.shape[0]}"
        )
    direction = null_tangent(jacobian, np.ones_like(q_start_rad))

    def f(q: FloatArray) -> FloatArray:
        return null_tangent(task_jacobian(kinematics, q, task), direction)

    points = [q_start_rad]
    q = q_start_rad.copy()
    closed, left_start = False, False
    for _ in range(int(max_length_rad / STEP_RAD)):
        stages: list[FloatArray] = []
        for coefficients in _A:
            q_stage = q + STEP_RAD * sum(
                (c * k for c, k in zip(coefficients, stages, strict=False)), np.zeros_like(q)
            )
            stages.append(f(q_stage))
        step = STEP_RAD * sum((b * k for b, k in zip(_B5, stages, strict=True)), np.zeros_like(q))
        direction = step / np.linalg.norm(step)
        q = wrap_periodic(q + step, torus)
        points.append(q)
        distance = float(joint_distance(q, q_start_rad, torus))
        left_start = left_start or distance > 2 * CLOSURE_RAD
        if left_start and distance < CLOSURE_RAD:
            closed = True
            break
    return Trace(
        q_rad=np.asarray(points),
        closed=closed,
        length_rad=STEP_RAD * (len(points) - 1),
        wall_time_ms=(time.perf_counter() - start) * 1e3,
    )
