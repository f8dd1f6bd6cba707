"""free_pieces through the whole pipeline: the planar 3R with a sphere on each link and an
obstacle across part of its self-motion. Every returned path point and configuration is
clear of it by the closed-form FK, the curve is cut there into pieces whose ends say
collision, a loop free all along stays closed, clearance is the least along the
component and the safest configuration the best, and the counts add up."""

from dataclasses import replace

import numpy as np
import pytest

from service.models.registry import ServedModel
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.collision.scene import Obstacle, Scene
from service.pipeline.connect.free_pieces import free_pieces
from service.pipeline.run import encode, run, space_of
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
