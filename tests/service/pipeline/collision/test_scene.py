"""scene: each obstacle's signed distance against its closed form (outside, on a face,
past an edge, inside), the pose taken into account, and bad obstacles refused naming
the field."""

import numpy as np
import pytest

from service.errors import RequestFieldError
from service.pipeline.collision.scene import Obstacle
from service.pipeline.rotations import quaternion_to_matrix

HALF_TURN_Z = (np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4))  # 90 deg about z


def clearance(obstacle: Obstacle, point: list[float], radius: float = 0.0) -> float:
    return float(obstacle.signed_distance_m(np.asarray(point, dtype=np.float64))) - radius


def test_box_distance_outside_past_an_edge_and_inside() -> None:
    box = Obstacle.of(0, "box", [0.2, 0.4, 0.6], [1.0, 0.0, 0.0], None)
    assert clearance(box, [1.5, 0.0, 0.0]) == pytest.approx(0.4)  # beyond the x face
    # Past the x-y edge: Euclidean distance to it.
    assert clearance(box, [1.4, 0.5, 0.0]) == pytest.approx(np.hypot(0.3, 0.3))
    assert clearance(box, [1.0, 0.0, 0.25]) == pytest.approx(-0.05)  # inside, nearest the z face
    assert clearance(box, [1.5, 0.0, 0.0], radius=0.1) == pytest.approx(0.3)


def test_box_pose_turns_its_sides() -> None:
    # Turned 90 deg about z, the 0.4 m side lies along x.
    box = Obstacle.of(0, "box", [0.2, 0.4, 0.6], [0.0, 0.0, 0.0], HALF_TURN_Z)
    assert clearance(box, [1.0, 0.0, 0.0]) == pytest.approx(0.8)
    assert clearance(box, [0.0, 1.0, 0.0]) == pytest.approx(0.9)


def test_sphere_cylinder_and_capsule_closed_forms() -> None:
    sphere = Obstacle.of(0, "sphere", [0.3], [0.0, 0.0, 1.0], None)
    assert clearance(sphere, [0.0, 0.4, 1.0]) == pytest.approx(0.1)
    assert clearance(sphere, [0.0, 0.0, 1.0]) == pytest.approx(-0.3)
    cylinder = Obstacle.of(0, "cylinder", [1.0, 0.2], [0.0, 0.0, 0.0], None)
    assert clearance(cylinder, [0.5, 0.0, 0.0]) == pytest.approx(0.3)  # beside the side
    assert clearance(cylinder, [0.0, 0.1, 0.8]) == pytest.approx(0.3)  # above the cap
    assert clearance(cylinder, [0.5, 0.0, 0.9]) == pytest.approx(np.hypot(0.3, 0.4))  # rim
    assert clearance(cylinder, [0.0, 0.0, 0.45]) == pytest.approx(-0.05)  # inside, by the cap
    capsule = Obstacle.of(0, "capsule", [1.0, 0.2], [0.0, 0.0, 0.0], None)
    assert clearance(capsule, [0.5, 0.0, 0.0]) == pytest.approx(0.3)
    assert clearance(capsule, [0.0, 0.0, 1.0]) == pytest.approx(0.3)  # cap centre at z 0.5
    assert clearance(capsule, [0.3, 0.0, 0.9]) == pytest.approx(0.3)  # 0.5 from the cap centre


def test_orientation_matches_the_target_convention() -> None:
    box = Obstacle.of(0, "box", [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], HALF_TURN_Z)
    np.testing.assert_allclose(box.rotation, quaternion_to_matrix(*HALF_TURN_Z))


@pytest.mark.parametrize(
    ("shape", "dimensions", "position", "orientation", "field"),
    [
        ("cone", [1.0], [0, 0, 0], None, "shape"),
        ("box", [1.0, 1.0], [0, 0, 0], None, "dimensions"),
        ("sphere", [-0.1], [0, 0, 0], None, "dimensions"),
        ("cylinder", [1.0, 0.0], [0, 0, 0], None, "dimensions"),
        ("capsule", [1000.0, 0.1], [0, 0, 0], None, "dimensions"),
        ("sphere", [0.1], [0, 0], None, "position"),
        ("box", [1.0, 1.0, 1.0], [0, 0, 0], (2.0, 0.0, 0.0, 0.0), "orientation"),
    ],
)
def test_bad_obstacles_are_refused_naming_the_field(
    shape: str,
    dimensions: list[float],
    position: list[float],
    orientation: tuple[float, float, float, float] | None,
    field: str,
) -> None:
    with pytest.raises(RequestFieldError) as refused:
        Obstacle.of(3, shape, dimensions, position, orientation)
    assert refused.value.location == ("body", "obstacles", 3, field)


@pytest.mark.parametrize(
    ("shape", "dimensions", "farthest"),
    [
        ("box", [0.2, 0.4, 0.6], [0.1, 0.2, 0.3]),  # a corner
        ("sphere", [0.3], [0.0, 0.3, 0.0]),
        ("cylinder", [1.0, 0.2], [0.2, 0.0, 0.5]),  # on the rim
        ("capsule", [1.0, 0.2], [0.0, 0.0, 0.7]),  # the tip of a cap
    ],
)
def test_reach_is_the_distance_to_the_farthest_point(
    shape: str, dimensions: list[float], farthest: list[float]
) -> None:
    """The sphere about the position that the two-pass bound relies on holds the solid:
    its radius is the distance to the solid's farthest point, which lies on its surface."""
    obstacle = Obstacle.of(0, shape, dimensions, [0.0, 0.0, 0.0], None)
    assert obstacle.reach_m == pytest.approx(np.linalg.norm(farthest))
    assert clearance(obstacle, farthest) == pytest.approx(0.0, abs=1e-12)
