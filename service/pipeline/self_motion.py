"""Self-motion between two configurations: a path on the fibre, inside the limits, from a
start to a goal of the same component, every point within the query's tolerance.

    start -> project onto the fibre -> answer (its samples with the start, and a goal
    configuration, among them) -> their components -> r = 1: the traced path between
    them; r > 1: the roadmap's shortest path, shortened and walked again finely

The start (and a goal configuration) may be off the fibre by up to `MAX_OFFSET_RAD`: Newton
brings it on, joints on a limit held (`FibreSpace.polish`); farther, or invalid there, it is
refused (RequestFieldError naming the field). A goal may instead be an objective over the
start's component: the node (r > 1) or path point (r = 1) farthest from the joint limits,
nearest a given configuration, or of greatest clearance (collisions checked).

The start and a goal configuration are added to the flow's samples (unless the model
draws in rounds, which run until the curves are found), so the connect stage decides their
components as any sample's: for r = 1 it traces the curve through each.
r = 1: the component's path is the whole curve in order, at most the path spacing apart; the
self-motion is its arc between the points nearest the start and the goal (the shorter way
round a closed loop), the exact start and goal at its ends.
r > 1: the roadmap's graph joins the start and goal nodes: Dijkstra over the edges (joint-metric
lengths), then shortcuts (from each node the farthest later node of the path that the
projected local planner walks straight to), then each leg walked again in steps of
`SPACING_RAD / stretch`, every step projected to the query's tolerance and checked as a
motion of the space; a leg that the straight walk cannot follow (a steered edge sliding
along a limit face) is walked by the steer instead, and an edge neither follows is left
out and the search runs again. Where the edges left no longer join start and goal, the
answer is `no_path`: the connect stage walked some edge at its coarser step (and 1e-4),
next to a singular set where the fibre turns faster than the path's spacing follows.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from service.errors import RequestFieldError
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.connect import (
    PlannerSettings,
    SteerSettings,
    planner_settings,
    steer,
    walk_on_fibre,
)
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.joint_space import JointLimits
from service.pipeline.run import (
    Stopwatch,
    answer,
    answer_in,
    encode,
    in_rounds,
    sample,
    space_of,
)
from service.pipeline.run import collision_of as collision_check_of
from service.pipeline.space import FibreSpace
from service.pipeline.types import Query, SmmModel, SmmResult

# The farthest a start or goal configuration may lie from the fibre, joint metric: a
# configuration a planner holds at the target (within a controller's tracking error) is
# far nearer; one farther away is at another target, and is refused.
MAX_OFFSET_RAD = 0.1
# Consecutive path points at most this far apart, joint metric (the answers' path spacing).
SPACING_RAD = 0.05
# A walked leg's length allowance, in chords, and so its step: SPACING_RAD / STRETCH.
STRETCH = 2.0
# Searches on the roadmap, each without the edges the one before could not walk.
MAX_SEARCHES = 4

# ok: a path; not_connected: start and goal on different components; no_path: one
# component, but no walk at the path's spacing and tolerance follows its roadmap (an edge
# the connect stage walked at its coarser step and tolerance, next to a singular set).
SelfMotionStatus = Literal["ok", "not_connected", "no_path"]
Objective = Literal["max_limit_margin", "nearest_to", "max_clearance"]
OBJECTIVES: tuple[Objective, ...] = ("max_limit_margin", "nearest_to", "max_clearance")


@dataclass(frozen=True)
class Goal:
    """A configuration to reach, or an objective over the start's component."""

    configuration_rad: FloatArray | None = None  # (n,)
    objective: Objective | None = None
    nearest_to_rad: FloatArray | None = None  # (n,) for "nearest_to"


@dataclass(frozen=True)
class SelfMotion:
    """The answer: a path from start to goal, or the components they lie on apart."""

    status: SelfMotionStatus
    path_rad: FloatArray | None  # (P, n) start first, goal last, at most SPACING_RAD apart
    length_rad: float | None  # joint-metric length of the path
    objective_value: float | None  # the objective's value at the goal (rad or m)
    start_component: int  # index into result.components
    goal_component: int  # likewise
    result: SmmResult  # the answer the path lies in (paths and roadmaps included)


def limit_margin_rad(q_rad: FloatArray, limits: JointLimits) -> FloatArray:  # (..., n) -> (...,)
    """The least distance of any limited joint to its nearer limit (inf with none)."""
    margin = np.minimum(q_rad - limits.lower_rad, limits.upper_rad - q_rad)
    return np.min(np.where(limits.periodic, np.inf, margin), axis=-1)


def self_motion(
    model: SmmModel,
    query: Query,
    start_rad: FloatArray,  # (n,)
    goal: Goal,
    deadline: Deadline = NO_DEADLINE,
) -> SelfMotion:
    """The self-motion from `start_rad` to `goal` on the query's fibre (module docstring)."""
    query = replace(query, include_paths=True, include_roadmap=True)
    watch = Stopwatch()
    with watch.stage("encode"):  # the target, and the start and goal onto its fibre
        target = encode(model, query)
        space = space_of(model, target, query.tolerance, collision_check_of(model, query))
        start = on_fibre(space, start_rad, "start")
        goal_q = None
        if goal.configuration_rad is not None:
            goal_q = on_fibre(space, goal.configuration_rad, ("goal", "configuration"))
    if in_rounds(model, query):  # r = 1, drawn until the curves are found
        result = answer(model, query, target, watch, deadline, space)
    else:  # the start and goal among the samples: a curve or roadmap through each
        extra = [start] if goal_q is None else [start, goal_q]
        with watch.stage("sample"):
            q_sampled = np.concatenate([sample(model, query, target, deadline), np.stack(extra)])
        result = answer_in(model, query, space, q_sampled, watch, deadline)
    if model.manifest.redundancy == 1:
        return _along_paths(space, result, start, goal, goal_q)
    return _on_roadmaps(space, model, result, start, goal, goal_q, deadline)


def on_fibre(space: FibreSpace, q_rad: FloatArray, field: str | tuple[str, ...]) -> FloatArray:
    """`q_rad` (n,) brought onto the fibre; RequestFieldError naming `field` where it lies
    farther than MAX_OFFSET_RAD from it or is not valid there."""
    location = ("body", field) if isinstance(field, str) else ("body", *field)
    name = ".".join(location[1:])
    q, ok = space.polish(np.asarray(q_rad, dtype=np.float64)[None], max_move_rad=MAX_OFFSET_RAD)
    if not ok[0]:
        raise RequestFieldError(
            location,
            f"{name} is not a valid configuration of this target's self-motion: it must lie "
            f"within {MAX_OFFSET_RAD} rad (joint metric) of a configuration that reaches "
            "the target within the tolerance, inside the joint limits and free of collision",
        )
    return q[0]


def _nearest(points_rad: FloatArray, q_rad: FloatArray, limits: JointLimits) -> tuple[int, float]:
    distance = limits.distance(points_rad, q_rad)
    index = int(np.argmin(distance))
    return index, float(distance[index])


def _nearest_on(
    points_rad: list[FloatArray | None],  # per component (k_c, n), None where it has none
    q_rad: FloatArray,  # (n,)
    limits: JointLimits,
) -> tuple[int, int, float]:
    """(component, row, distance) of the row nearest q_rad over every component's points."""
    best = (-1, -1, np.inf)
    for c, points in enumerate(points_rad):
        if points is not None and len(points):
            index, distance = _nearest(points, q_rad, limits)
            if distance < best[2]:
                best = (c, index, distance)
    return best


def _objective_index(
    points_rad: FloatArray,  # (P, n) candidates on the start's component
    goal: Goal,
    limits: JointLimits,
    clearance_m: FloatArray | None,  # (P,) where measured
) -> tuple[int, float]:
    """The candidate that best meets the goal's objective, and its value there
    (max_clearance needs the clearances: the route refuses it where nothing is checked)."""
    if goal.objective == "max_limit_margin":
        margin = limit_margin_rad(points_rad, limits)
        best = int(np.argmax(margin))
        return best, float(margin[best])
    if goal.objective == "nearest_to":
        assert goal.nearest_to_rad is not None
        return _nearest(points_rad, limits.wrap(goal.nearest_to_rad), limits)
    assert clearance_m is not None
    best = int(np.argmax(clearance_m))
    return best, float(clearance_m[best])


def _apart(start_component: int, goal_component: int, result: SmmResult) -> SelfMotion:
    return SelfMotion("not_connected", None, None, None, start_component, goal_component, result)


def _path_length(path_rad: FloatArray, limits: JointLimits) -> float:
    return float(limits.distance(path_rad[1:], path_rad[:-1]).sum()) if len(path_rad) > 1 else 0.0


# -- r = 1: along the traced paths ---------------------------------------------------------


def _along_paths(
    space: FibreSpace,
    result: SmmResult,
    start: FloatArray,
    goal: Goal,
    goal_q: FloatArray | None,
) -> SelfMotion:
    limits = space.limits
    components = result.components

    paths = [None if c.path is None else c.path.q_rad for c in components]

    def locate(q: FloatArray, field: tuple[str, ...]) -> tuple[int, int]:
        """(component, path point) nearest q; refused where no path passes within a spacing."""
        best = _nearest_on(paths, q, limits)
        if best[2] > SPACING_RAD:
            raise RequestFieldError(
                ("body", *field),
                f"{'.'.join(field)} lies on no component of this answer's self-motion "
                "(a piece the tracing did not reach): try another seed or more samples",
            )
        return best[0], best[1]

    start_component, start_index = locate(start, ("start",))
    path = components[start_component].path
    assert path is not None
    objective_value = None
    if goal_q is not None:
        goal_component, goal_index = locate(goal_q, ("goal", "configuration"))
    else:
        clearance = path.clearance_m
        goal_index, objective_value = _objective_index(path.q_rad, goal, limits, clearance)
        goal_component, goal_q = start_component, path.q_rad[goal_index]
    if goal_component != start_component:
        return SelfMotion(
            "not_connected", None, None, None, start_component, goal_component, result
        )
    arc = _arc(path.q_rad, start_index, goal_index, path.closed, limits)
    points = np.concatenate([start[None], arc, goal_q[None]])
    # The exact start and goal replace their path points where they coincide.
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = limits.distance(points[1:], points[:-1]) > 0.0
    points = points[keep]
    return SelfMotion(
        "ok", points, _path_length(points, limits), objective_value,
        start_component, goal_component, result,
    )  # fmt: skip


def _arc(path: FloatArray, a: int, b: int, closed: bool, limits: JointLimits) -> FloatArray:
    """Path points from index a to index b: along the path, or on a closed loop the shorter
    way round (P, n)."""
    if a <= b:
        forward = path[a : b + 1]
    else:
        forward = np.concatenate([path[a:], path[: b + 1]]) if closed else path[b : a + 1][::-1]
    if not closed:
        return forward
    backward = path[b : a + 1][::-1] if b <= a else np.concatenate([path[b:], path[: a + 1]])[::-1]
    shorter = _path_length(forward, limits) <= _path_length(backward, limits)
    return forward if shorter else backward


# -- r > 1: on the roadmaps ----------------------------------------------------------------


def _on_roadmaps(
    space: FibreSpace,
    model: SmmModel,
    result: SmmResult,
    start: FloatArray,
    goal: Goal,
    goal_q: FloatArray | None,
    deadline: Deadline,
) -> SelfMotion:
    limits = space.limits
    components = result.components

    members = [None if c.roadmap is None else c.roadmap.q_rad[: c.size] for c in components]

    def locate(q: FloatArray) -> tuple[int, int]:
        """(component, node) of the sample that q became: the nearest member of any roadmap."""
        component, node, _ = _nearest_on(members, q, limits)
        return component, node

    start_component, start_node = locate(start)
    roadmap = components[start_component].roadmap
    assert roadmap is not None
    objective_value = None
    if goal_q is not None:
        goal_component, goal_node = locate(goal_q)
    else:
        nodes = roadmap.q_rad
        clearance = None
        if space.collision.active:
            clearance = space.collision.clearances_m([nodes])[0]
        goal_node, objective_value = _objective_index(nodes, goal, limits, clearance)
        goal_component, goal_q = start_component, nodes[goal_node]
    if goal_component != start_component:
        return SelfMotion(
            "not_connected", None, None, None, start_component, goal_component, result
        )
    planner = planner_settings(model.manifest.defaults.connectivity)
    points = _roadmap_path(
        space, roadmap.q_rad, roadmap.edges, start_node, goal_node, planner, deadline
    )
    if points is None:
        return SelfMotion(
            "no_path", None, None, objective_value, start_component, goal_component, result
        )
    points[0], points[-1] = start, goal_q
    return SelfMotion(
        "ok", points, _path_length(points, limits), objective_value,
        start_component, goal_component, result,
    )  # fmt: skip


def _roadmap_path(
    space: FibreSpace,
    nodes: FloatArray,  # (M, n)
    edges: IntArray,  # (E, 2)
    start: int,
    goal: int,
    planner: PlannerSettings,
    deadline: Deadline,
) -> FloatArray | None:  # (P, n) from nodes[start] to nodes[goal]
    """Dijkstra over the edges, shortcuts, then each leg walked finely (module docstring);
    None where the edges left after the failed ones no longer join start and goal, or
    MAX_SEARCHES searches found no walkable route."""
    if start == goal:
        return nodes[[start]].copy()
    usable = np.ones(len(edges), dtype=bool)
    for _ in range(MAX_SEARCHES):
        route = _shortest(nodes, edges[usable], start, goal, space.limits)
        if route is None:
            return None
        legs = _shortcut(space, nodes, route, planner, deadline)
        walked, failed = _walk_legs(space, nodes, legs, deadline)
        if failed:  # a shortcut the fine walk cannot follow: its route's edges instead
            legs = _expand(legs, set(failed), route)
            walked, failed = _walk_legs(space, nodes, legs, deadline)
        if walked is not None:
            return walked
        unwalkable = {(min(a, b), max(a, b)) for a, b in failed}
        usable &= ~np.array([(min(a, b), max(a, b)) in unwalkable for a, b in edges.tolist()])
    return None


def _expand(
    legs: list[tuple[int, int]], failed: set[tuple[int, int]], route: list[int]
) -> list[tuple[int, int]]:
    """The legs with each failed one replaced by the route's edges it spans."""
    position = {node: k for k, node in enumerate(route)}
    expanded: list[tuple[int, int]] = []
    for leg in legs:
        if leg in failed:
            i, j = position[leg[0]], position[leg[1]]
            expanded += list(zip(route[i:j], route[i + 1 : j + 1], strict=True))
        else:
            expanded.append(leg)
    return expanded


def _shortest(
    nodes: FloatArray, edges: IntArray, start: int, goal: int, limits: JointLimits
) -> list[int] | None:
    """Node indices of the shortest route (joint-metric edge lengths) from start to goal;
    None where the edges do not join them."""
    length = limits.distance(nodes[edges[:, 0]], nodes[edges[:, 1]]) + 1e-12
    graph = coo_matrix((length, (edges[:, 0], edges[:, 1])), shape=(len(nodes), len(nodes)))
    _, previous = dijkstra(graph.tocsr(), directed=False, indices=start, return_predecessors=True)
    route = [goal]
    while route[-1] != start:
        before = int(previous[route[-1]])
        if before < 0:
            return None
        route.append(before)
    return route[::-1]


def _shortcut(
    space: FibreSpace,
    nodes: FloatArray,
    route: list[int],
    planner: PlannerSettings,
    deadline: Deadline,
) -> list[tuple[int, int]]:
    """Legs (a, b) over the route: from each node, the farthest later node of the route
    that the planner walks straight to (the next node when none further is)."""
    legs = []
    i = 0
    while i < len(route) - 1:
        later = np.arange(i + 2, len(route))
        j = i + 1
        if len(later):
            q_from = np.repeat(nodes[[route[i]]], len(later), axis=0)
            reached = walk_on_fibre(
                space, q_from, nodes[[route[k] for k in later]], planner, deadline=deadline,
                record=False,
            ).reached  # fmt: skip
            if reached.any():
                j = int(later[np.flatnonzero(reached).max()])
        legs.append((route[i], route[j]))
        i = j
    return legs


def _walk_legs(
    space: FibreSpace,
    nodes: FloatArray,
    legs: list[tuple[int, int]],
    deadline: Deadline,
) -> tuple[FloatArray | None, list[tuple[int, int]]]:
    """Every leg walked in steps of SPACING_RAD / STRETCH, each projected to the query's
    tolerance; a leg the straight walk does not follow is steered. The path (start node
    first, goal node last), or None with the legs neither walk followed."""
    tolerance = min(space.tolerance.position_m, space.tolerance.orientation_rad)
    fine = PlannerSettings(
        delta_rad=SPACING_RAD / STRETCH, lambda_=STRETCH, projection_tolerance=tolerance,
        projection_iterations=3, extra_iterations=4,
    )  # fmt: skip
    a = np.array([leg[0] for leg in legs])
    b = np.array([leg[1] for leg in legs])
    walks = walk_on_fibre(space, nodes[a], nodes[b], fine, deadline=deadline)
    pieces = list(walks.points_rad)
    failed = np.flatnonzero(~walks.reached)
    if len(failed):
        steering = SteerSettings(
            step_rad=SPACING_RAD / STRETCH, max_steps=2000, lambda_=STRETCH,
            projection_tolerance=tolerance, projection_iterations=4,
        )  # fmt: skip
        steered = steer(space, nodes[a[failed]], nodes[b[failed]], steering, deadline, record=True)
        for k, leg in enumerate(failed):
            pieces[leg] = steered.points_rad[k]
        failed = failed[~steered.arrived]
    if len(failed):
        return None, [(int(a[k]), int(b[k])) for k in failed]
    parts = [nodes[[a[0]]]]
    for k in range(len(legs)):
        parts += [pieces[k], nodes[[b[k]]]]
    return np.concatenate(parts), []
