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

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.space import FibreSpace
from service.pipeline.types import Component, ComponentPath, EndReason


def free_pieces(
    space: FibreSpace, components: list[Component], spacing_rad: float
) -> list[Component]:
    """The free pieces of the traced components (members not free are dropped: the
    acceptance counted them as rejected_collision); components with no path keep their
    free members."""
    parts = [c.q_rad for c in components] + [c.path.q_rad for c in components if c.path]
    clearances = space.collision.clearances_m(parts)
    of_members, of_paths = clearances[: len(components)], iter(clearances[len(components) :])
    margin_m = space.collision.margin_m
    pieces: list[Component] = []
    for component, member_clearance in zip(components, of_members, strict=True):
        free_members = _members(
            replace(component, clearance_m=member_clearance), member_clearance >= margin_m
        )
        if component.path is None:
            if len(free_members.q_rad):
                pieces.append(free_members)
            continue
        cut = _cut(space, component.path, next(of_paths))
        pieces += _assign(space, free_members, component.path, cut, spacing_rad)
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


def _assign(
    space: FibreSpace,
    members: Component,
    path: ComponentPath,
    cut: list[tuple[IntArray, ComponentPath]],
    spacing_rad: float,
) -> list[Component]:
    """Components of the pieces, each with the free members nearest one of its points."""
    piece_of_row = np.full(len(path.q_rad), -1)  # (P,) -1 where in collision
    for index, (rows, _) in enumerate(cut):
        piece_of_row[rows] = index
    free_rows = np.flatnonzero(piece_of_row >= 0)  # (F,)
    owner = np.full(len(members.q_rad), -1)
    if len(members.q_rad) and len(free_rows):
        limits = space.limits
        box = limits.box(np.concatenate([path.q_rad, members.q_rad]), margin_rad=1.0)
        _, nearest = box.tree(path.q_rad[free_rows]).query(box.points(members.q_rad))
        nearest_rows = free_rows[nearest]  # (k,)
        near = limits.distance(members.q_rad, path.q_rad[nearest_rows]) <= spacing_rad
        owner[near] = piece_of_row[nearest_rows[near]]
    pieces = [piece for _, piece in cut]
    components = [
        replace(_members(members, owner == index), path=piece) for index, piece in enumerate(pieces)
    ]
    for island in np.flatnonzero(owner < 0):  # no checked motion joins it to a piece
        only = _members(members, np.arange(len(owner)) == island)
        components.append(replace(only, path=None))
    return components
