"""Known self-motions: random walks on a target's fibre, inside the limits.

A walk from q0 joins q0 to every configuration it passes through by a path on the fibre,
so any two of its points lie on one component: the start and goal of a self-motion that
must exist (tools/self_motion_check.py, the connect stage's tests).
"""

from __future__ import annotations

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.fibre import Fibre, project
from service.pipeline.targets import target_reached


def pose_fibre(model: ServedModel, q_target: np.ndarray) -> Fibre:
    """The fibre of the pose (or position) that q_target (n,) reaches."""
    manifest = model.manifest
    fk = model.kinematics(q_target[None])
    target = target_reached(manifest.task, fk.position_m[0], fk.rotation[0])
    return Fibre(target=target, task=manifest.task, kinematics=model.kinematics, damping=1e-3)


def null_space_walk(
    model: ServedModel, q0: np.ndarray, steps: int, seed: int, held: int | None = None
) -> np.ndarray:
    """(k, n) configurations along a random walk on the fibre of q0's target: each step
    0.05 rad along the null-space part of a slowly turning random direction, projected
    back; a step that would leave the limits is not taken and the direction is redrawn.
    With `held`, that joint keeps its value: the step lies in the null space of J's
    other columns and the projection holds it."""
    fibre = pose_fibre(model, q0)
    limits = model.limits
    rng = np.random.default_rng(seed)
    n = len(q0)
    free = np.arange(n) != (-1 if held is None else held)
    locked = None if held is None else ~free[None]
    walk = [q0]
    heading = rng.normal(size=n)
    for _ in range(steps):
        q = walk[-1]
        _, jacobian = fibre.residual(q[None])
        heading = 0.9 * heading + 0.3 * rng.normal(size=n)
        j_free, h_free = jacobian[0][:, free], heading[free]
        d = np.zeros(n)
        d[free] = h_free - np.linalg.pinv(j_free) @ (j_free @ h_free)  # tangent part
        projected = project(fibre, (q + 0.05 * d / np.linalg.norm(d))[None], 4, locked=locked)
        nxt = projected.q_rad[0]
        inside = np.all((nxt >= limits.lower_rad) & (nxt <= limits.upper_rad))
        if projected.error_norm[0] < 1e-10 and inside:
            walk.append(nxt)
        else:
            heading = rng.normal(size=n)
    return np.asarray(walk)
