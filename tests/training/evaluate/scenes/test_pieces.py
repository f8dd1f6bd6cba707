"""training.evaluate.scenes.pieces: a curve cut by coal into free pieces, against a closed form.

A ball of radius b fixed R off the first joint's axis (of the small collision arm) sweeps
a circle as j1 turns; a spherical obstacle of radius s on that circle at angle phi0 is
touched when the centres are within b + s + margin, i.e. while |j1 - phi0| < delta with
delta = 2 arcsin((b + s + margin) / 2R). The curve j1 = t (other joints 0) is cut there:
an open sweep into two pieces of lengths phi0 - delta - start and end - phi0 - delta, a
loop around the full turn into one piece of 2 pi - 2 delta that wraps round the array's
end. The loop is j1 = 1 + cos t, j2 = sin t (a unit circle in joint space; j2 does not
move the ball) with the obstacle at j1 = 0 (t = pi): touched while cos t < -1 + delta,
so its free piece is t outside pi -+ arccos(1 - delta), of length 2 pi - 2 arccos(1 -
delta). Returned configurations are matched to the piece they lie on; a component on both
is a merge across the cut; one on two exact curves is a merge of curves.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.manifest import ChainSpec
from service.pipeline.collision.frames import chain_frames
from service.pipeline.collision.scene import Obstacle
from training.collision.geometry import Body, Shape
from training.evaluate.references.collision import CoalRobot
from training.evaluate.scenes.coal_model import CoalModel
from training.evaluate.scenes.pieces import (
    RESOLUTION_RAD,
    FreePieces,
    at_resolution,
    cut_curve,
    recall,
)

BALL_M, OBSTACLE_M, RADIUS_M, MARGIN_M = 0.03, 0.05, 0.4, 0.01
DELTA_RAD = 2 * np.arcsin((BALL_M + OBSTACLE_M + MARGIN_M) / (2 * RADIUS_M))


def _setup(arm_chain: ChainSpec, phi0: float) -> tuple[CoalModel, list[Obstacle]]:
    pose = np.eye(4)
    pose[0, 3] = RADIUS_M  # R along the frame's x: on the circle at angle j1
    ball = Body(link="l1", frame=1, shapes=(Shape("sphere", pose, (BALL_M,)),))
    coal = CoalModel(CoalRobot(arm_chain, [ball]), ())
    centre = chain_frames(arm_chain, np.array([[phi0, 0.0, 0.0, 0.0]]))[0, 1] @ pose
    return coal, [Obstacle.of(0, "sphere", [OBSTACLE_M], centre[:3, 3].tolist(), None)]


def _sweep(start: float, stop: float, closed: bool) -> np.ndarray:
    t = np.linspace(start, stop, 4001, endpoint=not closed)
    return at_resolution(np.stack([t, 0 * t, 0 * t, 0 * t], axis=1))


def test_an_open_sweep_is_cut_where_the_closed_form_says(arm_chain: ChainSpec) -> None:
    phi0 = 1.2
    coal, obstacles = _setup(arm_chain, phi0)
    q = _sweep(0.0, 2.8, closed=False)
    assert np.diff(q[:, 0]).max() <= RESOLUTION_RAD + 1e-3
    curve = cut_curve(q, False, coal.free(q, obstacles, MARGIN_M))
    expected = np.abs(q[:, 0] - phi0) >= DELTA_RAD
    # the points agree with the closed form but within one step of the boundary
    far = np.abs(np.abs(q[:, 0] - phi0) - DELTA_RAD) > 1e-6
    np.testing.assert_array_equal(curve.free[far], expected[far])
    np.testing.assert_allclose(
        curve.piece_length_rad, [phi0 - DELTA_RAD, 2.8 - phi0 - DELTA_RAD], atol=RESOLUTION_RAD
    )
    assert set(curve.piece[q[:, 0] < phi0 - DELTA_RAD]) == {0}
    assert set(curve.piece[q[:, 0] > phi0 + DELTA_RAD]) == {1}


def test_a_loop_is_one_piece_wrapping_round_its_end(arm_chain: ChainSpec) -> None:
    coal, obstacles = _setup(arm_chain, 0.0)
    t = np.linspace(0.0, 2 * np.pi, 8000, endpoint=False)
    q = at_resolution(np.stack([1 + np.cos(t), np.sin(t), 0 * t, 0 * t], axis=1))
    curve = cut_curve(q, True, coal.free(q, obstacles, MARGIN_M))
    assert len(curve.piece_length_rad) == 1
    expected = 2 * np.pi - 2 * np.arccos(1 - DELTA_RAD)
    assert curve.piece_length_rad[0] == pytest.approx(expected, abs=2 * RESOLUTION_RAD)
    assert curve.piece[0] == curve.piece[-1] == 0  # the run wraps round the array's end
    free_loop = cut_curve(q, True, np.ones(len(q), dtype=bool))
    assert free_loop.piece_length_rad[0] == pytest.approx(2 * np.pi, abs=1e-3)


def test_found_pieces_and_a_merge_across_the_cut(arm_chain: ChainSpec) -> None:
    phi0 = 1.2
    coal, obstacles = _setup(arm_chain, phi0)
    q = _sweep(0.0, 2.8, closed=False)
    pieces = FreePieces.of([cut_curve(q, False, coal.free(q, obstacles, MARGIN_M))], 2.8)
    periodic = np.zeros(4, dtype=bool)
    everywhere = np.ones(len(pieces.q_rad), dtype=bool)
    before, after = np.array([[0.3, 0, 0, 0]]), np.array([[2.5, 0, 0, 0]])
    only_first = recall(pieces, everywhere, before, np.zeros(1, int), periodic)
    assert (only_first.asked, only_first.found, only_first.merges) == (2, 1, 0)
    assert only_first.missed_length_rad == pytest.approx([2.8 - phi0 - DELTA_RAD], abs=0.03)
    both = np.concatenate([before, after])
    merged = recall(pieces, everywhere, both, np.zeros(2, int), periodic)
    assert (merged.found, merged.merges) == (2, 1)
    apart = recall(pieces, everywhere, both, np.arange(2), periodic)
    assert apart.merges == 0
    far = recall(pieces, everywhere, np.array([[0.3, 0.5, 0, 0]]), np.zeros(1, int), periodic)
    assert far.found == 0  # 0.5 rad off the curve: beyond the matching distance
    blocked = recall(pieces, np.zeros(len(pieces.q_rad), bool), before, np.zeros(1, int), periodic)
    assert (blocked.sphere_free, blocked.sphere_free_found) == (0, 0)


def test_a_component_on_two_exact_curves_is_no_cut_merge(arm_chain: ChainSpec) -> None:
    """Two curves, j2 = 0 and j2 = 1 (1 rad apart, beyond the matching distance; j2 does
    not move the ball, so the obstacle cuts both alike): a component on the first piece of
    each merges curves, not across a cut."""
    coal, obstacles = _setup(arm_chain, 1.2)
    first = _sweep(0.0, 2.8, closed=False)
    second = first + np.array([0.0, 1.0, 0.0, 0.0])
    curves = [cut_curve(q, False, coal.free(q, obstacles, MARGIN_M)) for q in (first, second)]
    pieces = FreePieces.of(curves, 5.6)
    assert pieces.curve.tolist() == [0, 0, 1, 1]
    periodic = np.zeros(4, dtype=bool)
    everywhere = np.ones(len(pieces.q_rad), dtype=bool)
    both = np.array([[0.3, 0.0, 0, 0], [0.3, 1.0, 0, 0]])
    found = recall(pieces, everywhere, both, np.zeros(2, int), periodic, kinematic=both)
    assert (found.merges, found.merges_of_curves) == (0, 1)
    assert found.missed_kinematically == [True, True]  # past the cut: neither answer has it
