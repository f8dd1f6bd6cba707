"""The baseline a user would otherwise pick: random-restart damped least squares.

pytorch-kinematics' PseudoInverseIK from restarts drawn uniformly in the joint limits (the
same number as the flow's samples), a fixed number of iterations, no early stopping. Its
raw solutions then go through the service's own acceptance, so the flow and this
baseline are judged by the same tolerance and limits. A position task sets the
orientation weight to zero.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pytorch_kinematics as pk
import torch

from service.manifest import JointSpec, TaskSpec
from service.pipeline.joint_space import JointLimits

ITERATIONS = 30  # pytorch-kinematics' README: iiwa, 30 iterations


@dataclass(frozen=True)
class RestartSolutions:
    q_rad: np.ndarray  # (N, n) one solution per restart, converged or not
    wall_time_ms: float


def random_restart_dls(
    chain: pk.SerialChain,
    joints: JointSpec,
    task: TaskSpec,
    position_m: np.ndarray,  # (3,) base frame; zeros on unconstrained axes
    rotation: np.ndarray | None,  # (3, 3) for a pose task
    num_restarts: int,
    seed: int,
    tolerance: float = 1e-6,
) -> RestartSolutions:
    """Solve one target from `num_restarts` uniform restarts; returns every final iterate."""
    limits = JointLimits.of(joints)
    restarts = np.random.default_rng(seed).uniform(
        limits.lower_rad, limits.upper_rad, (num_restarts, len(limits.lower_rad))
    )
    pose = np.eye(4)
    pose[:3, 3] = position_m
    if rotation is not None:
        pose[:3, :3] = rotation
    solver = pk.PseudoInverseIK(
        chain,
        retry_configs=torch.from_numpy(restarts),
        joint_limits=torch.from_numpy(np.stack([limits.lower_rad, limits.upper_rad], axis=1)),
        max_iterations=ITERATIONS,
        pos_tolerance=tolerance,
        rot_tolerance=tolerance if task.orientation else np.inf,
        orientation_weight=1.0 if task.orientation else 0.0,
        early_stopping_any_converged=False,
        early_stopping_no_improvement=None,
    )
    start = time.perf_counter()
    solution = solver.solve(pk.Transform3d(matrix=torch.from_numpy(pose[None]), dtype=chain.dtype))
    wall_time_ms = (time.perf_counter() - start) * 1e3
    return RestartSolutions(q_rad=solution.solutions[0].numpy(), wall_time_ms=wall_time_ms)
