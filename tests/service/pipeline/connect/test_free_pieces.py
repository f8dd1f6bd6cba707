"""free_pieces through the whole pipeline: the planar 3R with a sphere on each link and an
obstacle across part of its self-motion. Every returned path point and configuration is
clear of it by the closed-form FK, the curve is cut there into pieces whose ends say
collision, a loop free all along stays closed, clearance is the least along the
component and the safest configuration the best, and the counts add up. The acceptance
measures each sample on the fibre once, by the closed form, and free_pieces decides the
members by the clearances it is given, measuring only those it is not."""

from dataclasses import replace

import numpy as np
import pytest

from service.models.registry import ServedModel
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.collision.scene import Obstacle, Scene
from service.pipeline.connect.free_pieces import free_pieces
from service.pipeline.run import correct_samples, encode, run, sample, space_of
from service.pipeline.types import Component, ComponentSummary, Query
from tests.service.pipeline.collision.test_robot import (
    RADIUS_M,
    link_middles,
    planar_chain,
    planar_spec,
)

TARGET_M = [1.2, 0.9]
MARGIN_M = 0.02


@pytest.fixture(scope="module")
def with_spheres(planar3r: ServedModel) -> ServedModel:
    return replace(planar3r, robot_spheres=RobotSpheres.of(planar_chain(), planar_spec()))


def query(model: ServedModel, obstacles: list[Obstacle], margin_m: float = MARGIN_M) -> Query:
    return Query.for_model(
        model.manifest, position_m=TARGET_M, num_samples=500, seed=3,
        obstacles=obstacles, check_self=False, margin_m=margin_m,
    )  # fmt: skip


def clearance_closed_form(q: np.ndarray, centre: np.ndarray, radius: float) -> np.ndarray:
    middles = link_middles(q)  # (B, 3, 2), the three moving spheres
    return (np.linalg.norm(middles - centre, axis=2) - radius - RADIUS_M).min(axis=1)


def points(summary: ComponentSummary) -> np.ndarray:
    assert summary.path is not None
    return np.concatenate([summary.configurations_rad, summary.path.q_rad])


def test_a_curve_is_cut_where_it_enters_collision(with_spheres: ServedModel) -> None:
    free = run(with_spheres, query(with_spheres, []))
    assert free.components and all(c.clearance_m is None for c in free.components)
    # An obstacle on link 2's middle a third of the way along the longest path.
    longest = max(free.components, key=lambda c: c.arc_length_rad or 0.0)
    assert longest.path is not None
    q_hit = longest.path.q_rad[len(longest.path.q_rad) // 3]
    centre = link_middles(q_hit[None])[0, 1]
    obstacle = Obstacle.of(0, "sphere", [0.15], [*centre, 0.0], None)
    cut = run(with_spheres, query(with_spheres, [obstacle]))

    counts = cut.counts
    assert counts.rejected_collision > 0
    assert counts.sampled == (
        counts.accepted + counts.rejected_tolerance + counts.rejected_joint_limits
        + counts.rejected_collision
    )  # fmt: skip
    assert sum(c.size for c in cut.components) == counts.accepted
    ends = [end for c in cut.components for end in (c.ends or ())]
    assert "collision" in ends
    for component in cut.components:
        q = points(component)
        exact = clearance_closed_form(q, centre, 0.15)
        assert exact.min() >= MARGIN_M - 1e-12
        assert component.clearance_m == pytest.approx(exact.min(), abs=1e-12)
        assert component.safest_rad is not None
        best = clearance_closed_form(component.safest_rad[None], centre, 0.15)[0]
        assert best == pytest.approx(exact.max(), abs=1e-12)
        assert component.path is not None
        steps = np.linalg.norm(np.diff(component.path.q_rad, axis=0), axis=1)
        assert steps.max(initial=0.0) <= 0.05 + 1e-9  # no piece bridges the cut
    # The cut removed what the obstacle covers and nothing else: the free arc length
    # is the kinematic one less the points in collision, to the path spacing.
    assert sum(c.arc_length_rad or 0.0 for c in cut.components) < sum(
        c.arc_length_rad or 0.0 for c in free.components
    )


def test_a_far_obstacle_changes_nothing_but_clearance(with_spheres: ServedModel) -> None:
    far = Obstacle.of(0, "box", [0.1, 0.1, 0.1], [-3.5, -3.5, 0.0], None)
    free = run(with_spheres, query(with_spheres, []))
    checked = run(with_spheres, query(with_spheres, [far]))
    assert [c.size for c in checked.components] == [c.size for c in free.components]
    assert [c.closed for c in checked.components] == [c.closed for c in free.components]
    for before, after in zip(free.components, checked.components, strict=True):
        assert before.path is not None and after.path is not None
        np.testing.assert_array_equal(before.path.q_rad, after.path.q_rad)
        assert after.clearance_m is not None and after.clearance_m > 1.0


def test_no_curve_means_no_piece(with_spheres: ServedModel) -> None:
    """A target out of reach with the collision check on answers no component (no error)."""
    far = Query.for_model(
        with_spheres.manifest, position_m=[5.0, 0.0], num_samples=50, seed=0,
        obstacles=[Obstacle.of(0, "sphere", [0.1], [3.0, 3.0, 0.0], None)],
    )  # fmt: skip
    result = run(with_spheres, far)
    assert result.components == [] and result.counts.accepted == 0


def test_a_free_sample_off_every_free_path_point_is_a_component_of_its_own(
    with_spheres: ServedModel,
) -> None:
    """A free member farther than the path spacing from every free point of its curve
    (between two checked points that collide) joins no piece, and takes none of the
    uncut curve with it: a component of its own, no path."""
    free = run(with_spheres, query(with_spheres, []))
    path = max(free.components, key=lambda c: c.arc_length_rad or 0.0).path
    assert path is not None
    q_hit = path.q_rad[len(path.q_rad) // 2]
    centre = link_middles(q_hit[None])[0, 1]
    obstacle = Obstacle.of(0, "sphere", [0.15], [*centre, 0.0], None)
    asked = query(with_spheres, [obstacle])
    check = CollisionCheck(with_spheres.robot_spheres, Scene((obstacle,)), False, MARGIN_M)
    space = space_of(with_spheres, encode(with_spheres, asked), asked.tolerance, check)
    # The member: the colliding path point, turned at joint 1 until it is clear (off the
    # fibre, so farther than the spacing from every path point).
    member = q_hit + np.array([0.6, 0.0, 0.0])
    assert check.free(member[None])[0]
    alone = Component(q_rad=member[None], position_error_m=np.zeros(1),
                      orientation_error_rad=np.zeros(1), path=path)  # fmt: skip
    pieces = free_pieces(space, [alone], 0.05)
    islands = [p for p in pieces if p.path is None]
    assert len(islands) == 1 and np.array_equal(islands[0].q_rad, member[None])
    for piece in pieces:
        if piece.path is not None:
            assert check.free(piece.path.q_rad).all()


def test_the_acceptance_measures_every_sample_on_the_fibre_and_no_other(
    with_spheres: ServedModel,
) -> None:
    centre = np.array([0.9, 0.9])
    obstacle = Obstacle.of(0, "sphere", [0.15], [*centre, 0.0], None)
    asked = query(with_spheres, [obstacle])
    target = encode(with_spheres, asked)
    check = CollisionCheck(with_spheres.robot_spheres, Scene((obstacle,)), False, MARGIN_M)
    space = space_of(with_spheres, target, asked.tolerance, check)
    correction = correct_samples(with_spheres, space, sample(with_spheres, asked, target))
    acceptance = space.accept(correction)
    on_fibre = acceptance.on_fibre
    assert acceptance.clearance_m is not None and 0 < on_fibre.sum() < len(on_fibre)
    assert np.isnan(acceptance.clearance_m[~on_fibre]).all()
    exact = clearance_closed_form(correction.q_rad[on_fibre], centre, 0.15)
    np.testing.assert_allclose(acceptance.clearance_m[on_fibre], exact, rtol=0, atol=1e-12)
    assert 0 < (exact < MARGIN_M).sum() < len(exact)  # the obstacle takes some, not all
    np.testing.assert_array_equal(acceptance.collision_free[on_fibre], exact >= MARGIN_M)
    assert acceptance.collision_free[~on_fibre].all()  # nothing checked there
    # Judged without collisions, the samples keep their clearances for the pieces.
    kinematic = acceptance.kinematic()
    assert kinematic.accepted.sum() == on_fibre.sum()
    assert kinematic.clearance_m is acceptance.clearance_m


def test_free_pieces_takes_the_members_clearances_it_is_given(
    with_spheres: ServedModel,
) -> None:
    """A member whose given clearance is under the margin is dropped though it is free,
    one given a clearance over it keeps that figure, and one given none is measured."""
    asked = query(with_spheres, [])
    far = Obstacle.of(0, "box", [0.1, 0.1, 0.1], [-3.5, -3.5, 0.0], None)
    check = CollisionCheck(with_spheres.robot_spheres, Scene((far,)), False, MARGIN_M)
    space = space_of(with_spheres, encode(with_spheres, asked), asked.tolerance, check)
    traced = run(with_spheres, asked).components
    longest = max(traced, key=lambda c: c.arc_length_rad or 0.0)
    assert longest.path is not None and len(longest.configurations_rad) >= 3
    members = longest.configurations_rad[:3]
    measured = check.clearance_m(members)
    assert (measured > 1.0).all()  # far from the box: every member is free
    path = longest.path  # checked along it here: no clearances of its own yet
    assert path.clearance_m is None
    given = np.array([MARGIN_M / 2, 0.5, 0.7])  # the first under the margin
    component = Component(
        q_rad=members, position_error_m=np.zeros(3), orientation_error_rad=np.zeros(3),
        path=path, clearance_m=given,
    )  # fmt: skip
    (piece,) = free_pieces(space, [component], 0.05)
    np.testing.assert_array_equal(piece.q_rad, members[1:])
    assert piece.clearance_m is not None
    np.testing.assert_array_equal(piece.clearance_m, given[1:])
    unmeasured = replace(component, clearance_m=None)
    (piece,) = free_pieces(space, [unmeasured], 0.05)
    np.testing.assert_array_equal(piece.q_rad, members)
    assert piece.clearance_m is not None
    np.testing.assert_array_equal(piece.clearance_m, measured)
