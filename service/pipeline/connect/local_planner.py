"""The projected local planner: is there a path on the fibre, inside the limits, from a to b?

The check of constrained sampling-based planning (OMPL's ProjectedStateSpace,
`discreteGeodesic`; Kingston, Moll and Kavraki): from a, repeatedly step `delta` along
the joint-space segment toward b (the shorter way round only on periodic joints; a
limited joint never crosses its +-pi seam), project the step onto the fibre with Newton
(float64) and accept it only if it is a valid motion of the space (`FibreSpace.motion_valid`:
the projection converged, stayed inside the limits and did not jump, a step no longer
than lambda x delta and none across a coaxial set where the fibre does not reach it),
made progress toward b and the path so far is no longer than lambda x the chord. The
edge holds when b is within delta and the last hop to it crosses no coaxial set where the
fibre does not reach it (OMPL takes the last hop as it is: next to a singular set that
the fibre never reaches, two samples either side of it are closer than the step). With
`limit_check_rad`, each step and the last hop are also checked against the limits between
their ends at that finer spacing (`FibreSpace.inside_between`, as OMPL's motion validator
checks a motion at its own resolution): a step checked only where it lands can pass over
a sliver of the fibre outside the limits and join pieces they cut apart. A
failed edge is evidence that a and b lie on different components, so candidate edges may
be long without merging what is separate. All edges advance in lockstep: one batched
kinematics call per Newton iteration for every edge still walking.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import project
from service.pipeline.space import FibreSpace, LimitCheck


@dataclass(frozen=True)
class PlannerSettings:
    delta_rad: float  # step along the segment (OMPL: 0.05)
    lambda_: float  # largest step and path length, in delta and chord units (OMPL: 2)
    projection_tolerance: float  # |e| a projected step must reach (OMPL: 1e-4)
    projection_iterations: int = 2  # Newton steps per projected step ...
    extra_iterations: int = 3  # ... and up to this many more for a step not yet converged
    # Each step, and the last hop, also checked against the limits between its ends at this
    # spacing (FibreSpace.inside_between); None: a step is checked where it lands, as OMPL's.
    limit_check_rad: float | None = None


def edges_on_fibre(
    space: FibreSpace,
    q_from_rad: FloatArray,  # (E, n) valid configurations
    q_to_rad: FloatArray,  # (E, n) valid configurations
    settings: PlannerSettings,
    lambda_: float | None = None,  # overrides settings.lambda_
    deadline: Deadline = NO_DEADLINE,
) -> BoolArray:  # (E,) True where a path on the fibre joins the two ends
    """Walk every edge on the fibre in lockstep; True for the edges that reach their end."""
    return walk_on_fibre(
        space, q_from_rad, q_to_rad, settings, lambda_, deadline, record=False
    ).reached


@dataclass(frozen=True)
class Walks:
    """Where each edge's walk went: whether it reached its end, and (when recorded) the
    projected points it stepped through, in order (the start and the end not included)."""

    reached: BoolArray  # (E,)
    points_rad: list[FloatArray]  # per edge (k_e, n), empty unless recorded


def walk_on_fibre(
    space: FibreSpace,
    q_from_rad: FloatArray,  # (E, n) valid configurations
    q_to_rad: FloatArray,  # (E, n) valid configurations
    settings: PlannerSettings,
    lambda_: float | None = None,
    deadline: Deadline = NO_DEADLINE,
    record: bool = True,
) -> Walks:
    """`edges_on_fibre`, keeping the walks' points when `record` (to build a path from)."""
    num_edges = len(q_from_rad)
    reached = np.zeros(num_edges, dtype=bool)
    steps: list[tuple[IntArray, FloatArray]] = []  # per step: which edges moved, to where
    if num_edges == 0:
        return Walks(reached, [])
    stretch = settings.lambda_ if lambda_ is None else lambda_
    delta = settings.delta_rad
    fibre = space.fibre
    goal = q_from_rad + space.limits.difference(q_to_rad, q_from_rad)  # (E, n) unwrapped
    chord = np.linalg.norm(goal - q_from_rad, axis=1)  # (E,)
    q = q_from_rad.copy()
    travelled = np.zeros(num_edges)
    walking = np.ones(num_edges, dtype=bool)
    max_steps = int(np.ceil(stretch * chord.max() / delta)) + 2
    check = (
        None if settings.limit_check_rad is None else LimitCheck(settings.limit_check_rad, stretch)
    )
    rules = native.PlannerRules(
        delta, stretch, settings.projection_tolerance, settings.projection_iterations,
        settings.extra_iterations, max_steps,
        limit_check_rad=0.0 if check is None else check.spacing_rad,
    )  # fmt: skip
    compiled = _compiled_walks(space, q_from_rad, goal, chord, rules, deadline, record)
    if compiled is not None:
        return compiled
    for _ in range(max_steps):
        remaining = goal - q  # (E, n)
        distance = np.linalg.norm(remaining, axis=1)
        arrived = np.flatnonzero(walking & (distance <= delta))
        walking[arrived] = False
        tolerance = settings.projection_tolerance
        if space.coaxial_sets and len(arrived):  # the last hop, across no unreached set
            arrived = arrived[space.crossings_on_fibre(q[arrived], goal[arrived], tolerance)]
        if check is not None and len(arrived):  # ... and inside the limits between
            arrived = arrived[space.inside_between(q[arrived], goal[arrived], check, tolerance)]
        reached[arrived] = True
        if not walking.any():
            break
        deadline.check("connect")
        index = np.flatnonzero(walking)
        step = q[index] + delta * remaining[index] / distance[index, None]
        projected = project(fibre, step, settings.projection_iterations)
        q_new, error_norm = projected.q_rad, projected.error_norm  # (A, n), (A,)
        # Newton from a long step may need more iterations: only those rows get them.
        slow = np.flatnonzero(~(error_norm <= settings.projection_tolerance))
        for _ in range(settings.extra_iterations):
            if not len(slow):
                break
            again = project(fibre, q_new[slow], 1)
            q_new[slow], error_norm[slow] = again.q_rad, again.error_norm
            slow = slow[~(again.error_norm <= settings.projection_tolerance)]
        moved = np.linalg.norm(q_new - q[index], axis=1)
        nearer = np.linalg.norm(goal[index] - q_new, axis=1) < distance[index]
        no_detour = travelled[index] + moved <= stretch * chord[index]
        ok = space.motion_valid(
            q[index], q_new, error_norm, stretch * delta, tolerance, also=nearer & no_detour,
            limit_check=check,
        )  # fmt: skip
        walking[index[~ok]] = False
        q[index[ok]] = q_new[ok]
        travelled[index[ok]] += moved[ok]
        if record:
            steps.append((index[ok], q_new[ok]))
    if not record:
        return Walks(reached, [])
    return Walks(reached, points_per_walk(steps, num_edges, q.shape[1]))


def points_per_walk(
    steps: list[tuple[IntArray, FloatArray]],  # per lockstep step: which walks moved, to where
    num_walks: int,
    n: int,
) -> list[FloatArray]:  # per walk (k_w, n), in step order
    """The points of lockstep walks, walk by walk."""
    walk = np.concatenate([np.zeros(0, dtype=np.int64), *(rows for rows, _ in steps)])
    points = np.concatenate([np.zeros((0, n)), *(qs for _, qs in steps)])
    order = np.argsort(walk, kind="stable")  # each walk's points in step order
    bounds = np.searchsorted(walk[order], np.arange(num_walks + 1))
    return [points[order[bounds[w] : bounds[w + 1]]] for w in range(num_walks)]


def _compiled_walks(
    space: FibreSpace,
    q_from_rad: FloatArray,  # (E, n)
    goal_rad: FloatArray,  # (E, n) unwrapped toward q_from
    chord_rad: FloatArray,  # (E,)
    rules: native.PlannerRules,
    deadline: Deadline,
    record: bool,
) -> Walks | None:
    """The walks in compiled code (`native.projected_walk`, each edge whole, the same steps
    and tests as the loop above) where the space allows (`FibreSpace.compiled`); None
    otherwise."""
    compiled = space.compiled()
    if compiled is None:
        return None
    walked = native.projected_walk(
        compiled, q_from_rad, goal_rad, chord_rad, rules, deadline.expires_at_s, record,
        space.fibre.threads,
    )  # fmt: skip
    if walked.expired:
        deadline.check("connect")
    return Walks(walked.reached, walked.points_rad)
