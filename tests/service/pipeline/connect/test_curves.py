"""curves: which samples lie on the curves traced so far, and tracing those that do not.

`off_the_reached` measures on the joint torus, every joint a circle whether the limits bound
it or not (where the trace walks): a sample within the distance of a reached point is on,
one beyond it off, a turn of any joint changes nothing, every sample is off an empty set,
and on random points it agrees with the brute-force torus distance.
`extend_curves` on the planar 3R (two loops at 0.5 m, by the closed form of
training/evaluate/references/planar3r.py): samples on the traced loop add nothing and
count no stray; a sample of the other loop is traced, its loop added once, and the
reached points grow. The exact paths of all traced pieces measured at once equal each
piece's own, on real pieces and on pieces with an inexact point, a long step, a loop
opened there and no point.
`duplicate`: a path is one traced again only of a path on its own curve (the same arc
walked either way), not of one as long with ends elsewhere, a shorter one, a twin 0.03 rad
beside it or none; a NaN arc is like none.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.connect import extend_curves, trace_curves
from service.pipeline.connect.curves import (
    all_exact_paths,
    duplicate,
    exact_paths,
    off_the_reached,
)
from service.pipeline.connect.settings import trace_settings
from service.pipeline.connect.trace import trace_fibre
from service.pipeline.deadline import NO_DEADLINE
from service.pipeline.fibre import project
from service.pipeline.joint_space import JointLimits, wrap_to_pi
from service.pipeline.run import collision_of, encode, space_of
from service.pipeline.types import ComponentPath, Query
from training.evaluate.references.planar3r import closed_form_smm
from training.evaluate.served import orientation_wxyz
from training.evaluate.targets import uniform_configurations


def test_off_the_reached_measures_on_the_torus() -> None:
    reached = np.array([[3.1, 0.0], [0.0, 0.5]])
    q = np.array([[-3.1, 0.05], [0.0, 0.72], [0.0, 0.68], [1.5, 0.0]])
    # (-3.1, 0.05) is 0.083 + from (3.1, 0) across the wrap; 0.22 and 0.18 from (0, 0.5).
    assert off_the_reached(q, reached, 0.2).tolist() == [False, True, False, True]
    # A joint a turn or ten away (outside any limits) is the same point to the kinematics.
    turned = q + 2.0 * np.pi * np.array([[0, 1], [-3, 0], [10, -1], [1, 1]])
    assert off_the_reached(turned, reached, 0.2).tolist() == [False, True, False, True]
    assert off_the_reached(q, reached[:0], 0.2).all()


def test_off_the_reached_agrees_with_the_brute_force_torus_distance() -> None:
    rng = np.random.default_rng(3)
    reached = rng.uniform(-4.0, 4.0, size=(300, 7))
    q = rng.uniform(-20.0, 20.0, size=(200, 7))
    difference = wrap_to_pi(q[:, None, :] - reached[None, :, :])  # (200, 300, 7)
    nearest = np.linalg.norm(difference, axis=2).min(axis=1)  # (200,)
    within = float(np.median(nearest))
    assert off_the_reached(q, reached, within).tolist() == (nearest > within).tolist()


def test_extend_traces_only_samples_on_no_traced_curve(planar3r: ServedModel) -> None:
    query = Query.for_model(planar3r.manifest, position_m=[0.5, 0.0], seed=0)
    target = encode(planar3r, query)
    space = space_of(planar3r, target, query.tolerance, collision_of(planar3r, query))
    spec = planar3r.manifest.defaults.connectivity
    up, down = closed_form_smm(np.array([0.5, 0.0]), phi_step_rad=0.37)
    curves = trace_curves(space, up[:2], up[:2], spec, NO_DEADLINE).curves
    assert len(curves.paths) == 1 and len(curves.reached_rad) > 10
    same = extend_curves(curves, space, up[5:9], spec, NO_DEADLINE)
    assert same.curves is curves and same.strays == 0 and same.owner.tolist() == [0] * 4
    q_mixed = np.concatenate([up[3:4], down[2:3]])
    more = extend_curves(curves, space, q_mixed, spec, NO_DEADLINE)
    assert more.strays == 1 and len(more.curves.paths) == 2
    assert more.owner[0] == 0 and more.owner[1] == 1  # the new path is the down loop's
    assert len(more.curves.reached_rad) > len(curves.reached_rad)
    again = extend_curves(more.curves, space, down[4:6], spec, NO_DEADLINE)
    assert again.curves is more.curves and again.strays == 0 and again.owner.tolist() == [1, 1]


def test_all_exact_paths_equal_each_pieces_own() -> None:
    """Measuring every traced piece at once gives each piece's `exact_paths` answer,
    bitwise: on the iiwa14 pose's pieces (many, cut by the limits), and on pieces made to
    take the other way: a point off the fibre (left out), a step longer than two trace
    steps (a cut), a closed loop opened there, and an empty piece."""
    iiwa = load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)
    q_target = uniform_configurations(iiwa.limits, 1, seed=31)[0]
    fk = iiwa.kinematics(q_target[None])
    query = Query.for_model(
        iiwa.manifest, position_m=fk.position_m[0].tolist(),
        orientation_wxyz=orientation_wxyz(fk.rotation[0]), seed=0,
    )  # fmt: skip
    target = encode(iiwa, query)
    space = space_of(iiwa, target, query.tolerance, collision_of(iiwa, query)).kinematic()
    spec = iiwa.manifest.defaults.connectivity
    exact = project(space.fibre, q_target + np.random.default_rng(32).normal(0, 0.3, (300, 7)), 20)
    pieces = trace_fibre(space, exact.q_rad[exact.error_norm < 1e-9], trace_settings(spec)).pieces
    assert len(pieces) >= 3
    longest = max(pieces, key=lambda p: len(p.path_rad))
    off = longest.error.copy()
    off[len(off) // 2] += 1e-3  # off the fibre
    gap = np.delete(np.arange(len(longest.path_rad)), np.s_[5:25])  # a long step
    closed_gap = replace(longest, path_rad=longest.path_rad[gap], error=longest.error[gap])
    pieces += [
        replace(longest, error=off),
        replace(closed_gap, closed=True),
        replace(closed_gap, closed=False),
        replace(longest, path_rad=longest.path_rad[:0], error=longest.error[:0]),
    ]
    cut_rad = 2.0 * spec.trace_step_rad
    together = all_exact_paths(pieces, space, spec.path_spacing_rad, cut_rad)
    alone = [exact_paths(piece, space, spec.path_spacing_rad, cut_rad) for piece in pieces]
    assert len(together) == len(alone)
    for (paths, whole), (paths_alone, whole_alone) in zip(together, alone, strict=True):
        assert whole == whole_alone and len(paths) == len(paths_alone)
        for a, b in zip(paths, paths_alone, strict=True):
            assert (a.closed, a.arc_length_rad) == (b.closed, b.arc_length_rad)
            for x, y in ((a.q_rad, b.q_rad), (a.position_error_m, b.position_error_m),
                         (a.orientation_error_rad, b.orientation_error_rad)):  # fmt: skip
                np.testing.assert_array_equal(x, y)
    assert [len(p) for p, _ in together[-4:]] == [1, 2, 2, 0]


def _arc_path(centre: tuple[float, float], start: float, stop: float) -> ComponentPath:
    """An open arc of radius 1 about `centre` in a 2-joint space, at 0.02 rad."""
    angle = np.linspace(start, stop, int(np.ceil((stop - start) / 0.02)) + 1)
    q = np.stack([centre[0] + np.cos(angle), centre[1] + np.sin(angle)], axis=1)
    arc = float(np.linalg.norm(np.diff(q, axis=0), axis=1).sum())
    zeros = np.zeros(len(q))
    return ComponentPath(q, zeros, zeros, closed=False, arc_length_rad=arc)


def test_a_path_is_a_duplicate_only_of_one_on_the_same_curve() -> None:
    limits = JointLimits(np.full(2, -10.0), np.full(2, 10.0), np.zeros(2, dtype=bool))
    arc = _arc_path((0.0, 0.0), 0.0, 2.0)
    again = replace(arc, q_rad=arc.q_rad[::-1].copy())  # the same curve walked back
    moved = _arc_path((0.3, 0.0), 0.0, 2.0)  # as long, ends 0.3 rad away: another curve
    shorter = _arc_path((0.0, 0.0), 0.0, 1.5)
    twin = _arc_path((0.0, 0.03), 0.0, 2.0)  # 0.03 rad beside it, ends within the spacing
    others = [moved, shorter, twin]
    assert not duplicate(arc, [], limits, 0.05)
    assert not duplicate(arc, others, limits, 0.05)
    assert duplicate(arc, [*others, again], limits, 0.05)
    assert duplicate(again, [moved, arc], limits, 0.05)
    # The arc-length test comes first: a NaN arc is like none.
    assert not duplicate(replace(arc, arc_length_rad=float("nan")), [again], limits, 0.05)
