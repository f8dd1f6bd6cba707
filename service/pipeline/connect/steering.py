"""Steering on the fibre: walk from a toward b in the fibre's tangent space, sliding along
the joint limits.

The projected local planner (local_planner.py) follows the joint-space segment a-b, so it
fails wherever a component bends away from that segment or is cut by a joint limit across
it: the thin pieces that the limits leave of a 4-D fibre are often such. The steer walks
instead along the part of the direction to b that the fibre allows: the direction
b - q projected onto the null space of J, with each joint that sits on a limit and is
pushed further out held fixed, so the walk slides along the limit face (the
gradient-projection step of constrained optimisation, on the fibre). Each step, at most
`step_rad` long, ends inside the limits (a joint that would cross one stops on it), is
projected back onto the fibre with Newton (the joints on a limit held) and is checked as
the planner checks its steps: converged within tolerance, inside the limits, no jump (a
move longer than lambda x the step, or across a coaxial set where the fibre does not
reach it) and, with `limit_check_rad`, inside the limits between its ends too. A walk
ends when it is within one step of b (arrived), when a step fails, or when it stops
getting nearer to b (a local minimum of the distance on the fibre). Every walk's steps
form a path on the fibre inside the limits, from a to where it ended. All walks advance
in lockstep: one batched kinematics call per Newton iteration for every walk still going.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.local_planner import points_per_walk
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import evaluate, newton
from service.pipeline.space import FibreSpace, LimitCheck


@dataclass(frozen=True)
class SteerSettings:
    step_rad: float  # longest step along the tangent
    max_steps: int  # steps per walk at most
    lambda_: float  # a projected step may move at most lambda x step_rad
    projection_tolerance: float  # |e| a projected step must reach
    projection_iterations: int = 4  # Newton steps per projected step (rows stop once within)
    stall_steps: int = 8  # end a walk that got no nearer to b over this many steps ...
    min_progress_rad: float = 0.02  # ... by at least this much
    # Each step also checked against the limits between its ends at this spacing
    # (FibreSpace.inside_between); None: where it lands only.
    limit_check_rad: float | None = None


@dataclass(frozen=True)
class Steer:
    """Where each walk ended, on the fibre and inside the limits, whether it got to b, and
    (when recorded) the points it stepped through, in order, its end included."""

    q_end_rad: FloatArray  # (E, n) joined to its start by a path on the fibre
    arrived: BoolArray  # (E,) within one step of b (b itself is then joined too)
    points_rad: list[FloatArray] = field(default_factory=list)  # per walk (k_e, n) if recorded


def steer(
    space: FibreSpace,
    q_from_rad: FloatArray,  # (E, n) valid configurations
    q_to_rad: FloatArray,  # (E, n)
    settings: SteerSettings,
    deadline: Deadline = NO_DEADLINE,
    record: bool = False,
) -> Steer:
    """Walk every a toward its b on the fibre; the walks advance in lockstep. `record`
    keeps each walk's points (the numpy loop: the compiled walk keeps only its end)."""
    fibre, limits = space.fibre, space.limits
    lower_rad, upper_rad, periodic = limits.lower_rad, limits.upper_rad, limits.periodic
    num_walks = len(q_from_rad)
    goal = q_from_rad + limits.difference(q_to_rad, q_from_rad)  # (E, n) unwrapped
    check = (
        None
        if settings.limit_check_rad is None
        else LimitCheck(settings.limit_check_rad, settings.lambda_)
    )
    compiled = None if record else space.compiled()
    if compiled is not None:  # the same walks, each whole in compiled code
        rules = native.SteerRules(
            settings.step_rad, settings.max_steps, settings.lambda_,
            settings.projection_tolerance, settings.projection_iterations,
            settings.stall_steps, settings.min_progress_rad,
            limit_check_rad=0.0 if check is None else check.spacing_rad,
        )  # fmt: skip
        steered = native.steer_walk(
            compiled, q_from_rad, goal, rules, deadline.expires_at_s, space.fibre.threads
        )
        if steered.expired:
            deadline.check("connect")
        return Steer(q_end_rad=limits.wrap(steered.q_end_rad), arrived=steered.arrived)
    state = evaluate(fibre, q_from_rad.copy())
    q, jacobian = state.q_rad.copy(), state.jacobian.copy()  # (E, n), (E, m, n)
    arrived = np.zeros(num_walks, dtype=bool)
    walking = np.ones(num_walks, dtype=bool)
    steps: list[tuple[IntArray, FloatArray]] = []  # per step: which walks moved, to where
    best = np.linalg.norm(goal - q, axis=1)  # (E,) nearest to b so far
    since_best = np.zeros(num_walks, dtype=np.int64)  # steps since `best` last improved
    for _ in range(settings.max_steps):
        remaining = goal - q  # (E, n)
        distance = np.linalg.norm(remaining, axis=1)
        arrived |= walking & (distance <= settings.step_rad)
        walking &= ~arrived
        if not walking.any():
            break
        deadline.check("connect")
        index = np.flatnonzero(walking)  # (A,)
        q_a, lower_side, upper_side = q[index], q[index] <= lower_rad, q[index] >= upper_rad
        pushed_out = (lower_side & (remaining[index] < 0)) | (upper_side & (remaining[index] > 0))
        held = pushed_out & ~periodic  # (A, n) joints on a limit that the direction pushes out
        direction = tangent_direction(jacobian[index], remaining[index], held)  # (A, n)
        length = np.linalg.norm(direction, axis=1)
        moving = length > 1e-9
        step = (
            direction
            * (np.minimum(settings.step_rad, length) / np.maximum(length, 1e-300))[:, None]
        )
        guess = limits.clip(q_a + step)  # (A, n) a joint that would cross a limit stops on it
        on_limit = ~periodic & ((guess <= lower_rad) | (guess >= upper_rad))  # (A, n)
        tolerance = settings.projection_tolerance
        start = evaluate(fibre, guess)
        projected = newton(
            fibre, start, settings.projection_iterations, locked=on_limit, until=tolerance
        )
        q_new = projected.q_rad
        max_move_rad = settings.lambda_ * settings.step_rad
        ok = space.motion_valid(
            q_a, q_new, projected.error_norm, max_move_rad, tolerance, also=moving,
            limit_check=check,
        )  # fmt: skip
        walking[index[~ok]] = False
        good = index[ok]
        q[good] = q_new[ok]
        jacobian[good] = projected.jacobian[ok]
        if record:
            steps.append((good, q_new[ok]))
        now = np.linalg.norm(goal[good] - q[good], axis=1)
        improved = now < best[good] - settings.min_progress_rad
        best[good] = np.where(improved, now, best[good])
        since_best[good] = np.where(improved, 0, since_best[good] + 1)
        walking[good[since_best[good] >= settings.stall_steps]] = False
    arrived |= walking & (np.linalg.norm(goal - q, axis=1) <= settings.step_rad)
    points: list[FloatArray] = []
    if record:
        points = [limits.wrap(p) for p in points_per_walk(steps, num_walks, q.shape[1])]
    return Steer(q_end_rad=limits.wrap(q), arrived=arrived, points_rad=points)


def tangent_direction(
    jacobian: FloatArray,  # (A, m, n)
    wanted: FloatArray,  # (A, n) the direction asked for
    held: BoolArray,  # (A, n) joints that must not move
) -> FloatArray:  # (A, n) the nearest direction with J d = 0 and d = 0 on held joints
    """Least-squares projection of `wanted` onto the null space of J, held joints fixed."""
    free = ~held
    j_free = jacobian * free[:, None, :]  # (A, m, n) held columns zeroed
    g = wanted * free  # (A, n)
    gram = j_free @ np.swapaxes(j_free, 1, 2)  # (A, m, m)
    gram += 1e-9 * np.eye(gram.shape[1])[None]
    y = np.linalg.solve(gram, (j_free @ g[:, :, None]))  # (A, m, 1)
    return g - (np.swapaxes(j_free, 1, 2) @ y)[..., 0]
