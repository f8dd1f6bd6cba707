"""r = 1 with collisions: every traced curve cut where it enters collision.

The trace follows each curve of the fibre whole inside the limits, collisions aside
(`FibreSpace.kinematic`), so that a free piece is found even when no sample landed on
it, only elsewhere on its curve. Here every path point (consecutive points at most the
path spacing apart: the resolution a motion along the path is checked at) is checked,
and each maximal run of free points is a component of the free fibre: its ends say why
it ends, at a joint limit (the curve's own end) or where the curve enters collision. A
loop that is free all along stays whole and closed. Each free sample joins the piece of
its nearest free path point; one farther than the path spacing from any (a free island
between two checked points) is a component of its own, since no checked motion joins it
to a piece.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.space import FibreSpace
from service.pipeline.types import Component, ComponentPath, EndReason


def free_pieces(
    space: FibreSpace, components: list[Component], spacing_rad: float
) -> list[Component]:
    """The free pieces of the traced components (members not free are dropped: the
    acceptance counted them as rejected_collision); components with no path keep their
    free members. The members' clearances are the acceptance's where it measured them."""
    parts = [c.q_rad for c in components if c.clearance_m is None]
    parts += [c.path.q_rad for c in components if c.path]
    clearances = iter(space.collision.clearances_m(parts))
    of_members = [
        c.clearance_m if c.clearance_m is not None else next(clearances) for c in components
    ]
    of_paths = clearances  # the rest, in the paths' order
    margin_m = space.collision.margin_m
    kept: list[Component] = []  # each component's free members
    cuts: list[list[tuple[IntArray, ComponentPath]] | None] = []  # its path's free runs
    for component, member_clearance in zip(components, of_members, strict=True):
        free = member_clearance >= margin_m
        measured = replace(component, clearance_m=member_clearance)
        kept.append(measured if free.all() else _members(measured, free))
        path = component.path
        cuts.append(None if path is None else _cut(space, path, next(of_paths)))
    owners = _nearest_pieces(space, kept, cuts, spacing_rad)
    pieces: list[Component] = []
    for members, cut, owner in zip(kept, cuts, owners, strict=True):
        if cut is None:
            if len(members.q_rad):
                pieces.append(members)
            continue
        pieces += _assign(members, cut, owner)
    return pieces


def _members(component: Component, keep: BoolArray) -> Component:
    """The component with only the members `keep` (and their clearance)."""
    clearance = component.clearance_m
    return replace(
        component,
        q_rad=component.q_rad[keep],
        position_error_m=component.position_error_m[keep],
        orientation_error_rad=component.orientation_error_rad[keep],
        clearance_m=None if clearance is None else clearance[keep],
    )


def _cut(
    space: FibreSpace, path: ComponentPath, clearance: FloatArray
) -> list[tuple[IntArray, ComponentPath]]:
    """Maximal runs of free points of `path`: their rows (R,) of it, and each as a path
    with its ends' reasons."""
    free = clearance >= space.collision.margin_m  # (P,)
    if free.all():
        return [(np.arange(len(free)), replace(path, clearance_m=clearance))]
    order = np.arange(len(free))
    if path.closed:  # start the loop at a point in collision: no run wraps around
        order = np.roll(order, -int(np.flatnonzero(~free)[0]))
    edges = np.diff(np.concatenate([[0], free[order].astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)  # runs [a, b)
    paths = []
    for start, stop in zip(starts, stops, strict=True):
        rows = order[start:stop]
        q = path.q_rad[rows]
        first: EndReason = "joint_limit" if start == 0 and not path.closed else "collision"
        last: EndReason = "joint_limit" if stop == len(free) and not path.closed else "collision"
        paths.append(
            (
                rows,
                ComponentPath(
                    q_rad=q,
                    position_error_m=path.position_error_m[rows],
                    orientation_error_rad=path.orientation_error_rad[rows],
                    closed=False,
                    arc_length_rad=float(space.limits.distance(q[1:], q[:-1]).sum()),
                    ends=(first, last),
                    clearance_m=clearance[rows],
                ),
            )
        )
    return paths


def _nearest_pieces(
    space: FibreSpace,
    members: list[Component],
    cuts: list[list[tuple[IntArray, ComponentPath]] | None],
    spacing_rad: float,
) -> list[IntArray]:
    """For each component with a path, the piece of its path each free member joins: the
    piece of its nearest free path point when that is within the spacing, -1 (an island)
    otherwise; empty for a component without a path.

    Each member is measured against its own component's free path points only, by brute
    force (`native.nearest_in_group`): tens of members against a hundred points or so per
    component, where one KD-tree over every component's points, grouped by an extra
    coordinate, took this function from 0.55 to 0.95 ms an answer (iiwa14 pose, N = 500,
    about 20 components a target).
    """
    limits = space.limits
    points, point_piece, point_group, queries, query_group = [], [], [], [], []
    asking: list[int] = []  # the components whose members are queried, in order
    for group, (component, cut) in enumerate(zip(members, cuts, strict=True)):
        if cut is None or not len(component.q_rad):
            continue
        for index, (rows, piece) in enumerate(cut):
            points.append(piece.q_rad)
            point_piece.append(np.full(len(rows), index))
            point_group.append(np.full(len(rows), group))
        queries.append(component.q_rad)
        query_group.append(np.full(len(component.q_rad), group))
        asking.append(group)
    owners = [
        np.full(0 if cut is None else len(c.q_rad), -1)
        for c, cut in zip(members, cuts, strict=True)
    ]
    if not points or not queries:
        return owners
    q_points, q_queries = np.concatenate(points), np.concatenate(queries)  # (P, n), (Q, n)
    of_point, group_of_point = np.concatenate(point_piece), np.concatenate(point_group)
    group_of_query = np.concatenate(query_group)
    nearest = native.nearest_in_group(
        q_points, group_of_point, q_queries, group_of_query, limits.periodic
    )  # (Q,) -1 where the member's component has no free point
    same = nearest >= 0
    near = np.zeros(len(q_queries), dtype=bool)
    near[same] = limits.distance(q_queries[same], q_points[nearest[same]]) <= spacing_rad
    owner = np.where(near, of_point[nearest], -1)
    bounds = np.cumsum([0] + [len(q) for q in queries])
    for g, group in enumerate(asking):
        owners[group] = owner[bounds[g] : bounds[g + 1]]
    return owners


def _assign(
    members: Component, cut: list[tuple[IntArray, ComponentPath]], owner: IntArray
) -> list[Component]:
    """Components of the pieces, each with the free members `owner` gives it (-1: an
    island of its own, since no checked motion joins it to a piece)."""
    if len(cut) == 1 and np.all(owner == 0):  # the usual case: one free piece has them all
        return [replace(members, path=cut[0][1])]
    components = [
        replace(_members(members, owner == index), path=piece)
        for index, (_, piece) in enumerate(cut)
    ]
    for island in np.flatnonzero(owner < 0):
        only = _members(members, np.arange(len(owner)) == island)
        components.append(replace(only, path=None))
    return components
