"""steering: the tangent direction is the least-squares nearest one with J d = 0 and the
held joints still (against an explicit null-space basis); on the iiwa14's position fibre a
walk steered from one end of a null-space random walk reaches the other end, every step
exact by the DH table and inside the limits; walks between the elbow-up and elbow-down
components, which no path joins, never arrive and never change the sign of q4; a walk
whose straight way out is blocked by a joint limit slides along it to its goal (with the
limit check too), and recorded it keeps the points where walks of each number of steps
end; and the compiled
walks take the numpy loop's steps on the iiwa14's and Panda's r = 4 fibres."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import null_space

from service.errors import DeadlineExceededError
from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.connect.steering import SteerSettings, steer, tangent_direction
from service.pipeline.deadline import Deadline
from service.pipeline.fibre import Fibre
from service.pipeline.joint_space import JointLimits
from service.pipeline.space import FibreSpace
from tests.service.pipeline.fibre_support import (
    fibre_space,
    null_space_walk,
    obstacle_scene,
    pose_fibre,
    served_position_spaces,
)
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose

SETTINGS = SteerSettings(step_rad=0.15, max_steps=100, lambda_=2.0, projection_tolerance=1e-4)
CHECKED = replace(SETTINGS, limit_check_rad=0.02)  # each step's interior checked too


@pytest.fixture(scope="module")
def iiwa14_position() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)


def test_tangent_direction_is_the_projection_onto_the_free_null_space() -> None:
    rng = np.random.default_rng(0)
    jacobian = rng.normal(size=(20, 3, 7))
    wanted = rng.normal(size=(20, 7))
    held = rng.random((20, 7)) < 0.3
    held[:, :3] = False  # at least 4 free joints: a null space remains
    direction = tangent_direction(jacobian, wanted, held)
    for row in range(20):
        free = ~held[row]
        basis = null_space(jacobian[row][:, free])  # orthonormal, (free, free - 3)
        expected = np.zeros(7)
        expected[free] = basis @ (basis.T @ wanted[row, free])
        np.testing.assert_allclose(direction[row], expected, atol=1e-7)
        np.testing.assert_allclose(jacobian[row] @ direction[row], 0.0, atol=1e-7)
        assert np.all(direction[row, held[row]] == 0.0)


def assert_on_fibre(points: np.ndarray, q0: np.ndarray) -> None:
    """Every configuration (k, 7) reaches q0's position within the projection tolerance,
    by the DH table (independent of the service's kinematics)."""
    error = iiwa14_pose(points)[:, :3, 3] - iiwa14_pose(q0[None])[0, :3, 3]
    assert np.linalg.norm(error, axis=1).max() <= SETTINGS.projection_tolerance


def space(fibre: Fibre, limits: JointLimits) -> FibreSpace:
    """The space on `fibre` inside `limits`, with no coaxial set a walk must check."""
    return fibre_space(fibre, limits, ())


def _walk_points(space: FibreSpace, start: np.ndarray, goal: np.ndarray) -> list[np.ndarray]:
    """The configurations a steered walk visits, one step of the walk at a time."""
    points = [start]
    for steps in range(1, SETTINGS.max_steps + 1):
        settings = SteerSettings(**{**SETTINGS.__dict__, "max_steps": steps})
        walk = steer(space, start[None], goal[None], settings)
        points.append(walk.q_end_rad[0])
        if walk.arrived[0] or np.array_equal(points[-1], points[-2]):
            break
    return points


def test_a_walk_reaches_the_far_end_of_a_random_walk_on_one_component(
    iiwa14_position: ServedModel,
) -> None:
    limits = iiwa14_position.limits
    q0 = np.array([0.3, 0.5, -0.4, -1.3, 0.6, 0.9, 0.2])
    path = null_space_walk(iiwa14_position, q0, steps=400, seed=0)
    start, goal = path[0], path[-1]
    assert np.linalg.norm(goal - start) > 1.0
    on_fibre = space(pose_fibre(iiwa14_position, q0), limits)
    walk = steer(on_fibre, start[None], goal[None], SETTINGS)
    assert walk.arrived[0]
    assert np.linalg.norm(walk.q_end_rad[0] - goal) <= SETTINGS.step_rad
    # Every step of the walk is on the fibre (DH table, independent of the service),
    # inside the limits, and no step jumps.
    points = np.stack(_walk_points(on_fibre, start, goal))
    assert_on_fibre(points, q0)
    assert np.all((points >= limits.lower_rad) & (points <= limits.upper_rad))
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    assert steps.max() <= SETTINGS.lambda_ * SETTINGS.step_rad


def test_walks_between_elbow_up_and_down_never_arrive(iiwa14_position: ServedModel) -> None:
    # 0.674 m from the shoulder: q4 = 0 would put the end effector 0.82 +- 0.126 m from
    # it, so no path on this fibre changes the sign of q4 (test_roadmap has the same target).
    limits = iiwa14_position.limits
    up = np.array([0.3, 0.5, -0.4, 1.3, 0.6, 0.9, 0.2])
    fibre = pose_fibre(iiwa14_position, up)
    down = null_space_walk(iiwa14_position, up, steps=60, seed=2)
    down = down * np.array([1, -1, 1, -1, 1, -1, 1])  # the mirror: q2, q4, q6 negated
    np.testing.assert_allclose(iiwa14_pose(down)[:, :3, 3].std(axis=0), 0.0, atol=1e-3)
    start = np.repeat(up[None], len(down), axis=0)
    walk = steer(space(fibre, limits), start, down, SETTINGS)
    assert not walk.arrived.any()
    assert np.all(walk.q_end_rad[:, 3] > 0.0)


def test_a_walk_slides_along_a_joint_limit_to_its_goal(iiwa14_position: ServedModel) -> None:
    # Start and goal joined by a path with q6 held at 0.9 (so they are one component when
    # q6 may not exceed 0.9); the walk with the usual limits overshoots 0.9, so with that
    # limit it must hold q6 on it and slide.
    limits = iiwa14_position.limits
    q0 = np.array([0.3, 0.5, -0.4, -1.3, 0.6, 0.9, 0.2])
    witness = null_space_walk(iiwa14_position, q0, steps=300, seed=1, held=5)
    start, goal = witness[0], witness[-1]
    assert np.linalg.norm(goal - start) > 2.0 and np.all(witness[:, 5] == 0.9)
    fibre = pose_fibre(iiwa14_position, q0)
    unlimited = np.stack(_walk_points(space(fibre, limits), start, goal))
    assert unlimited[:, 5].max() > 0.9 + 0.05
    limited_upper = limits.upper_rad.copy()
    limited_upper[5] = 0.9
    limited = space(fibre, JointLimits(limits.lower_rad, limited_upper, limits.periodic))
    walk = steer(limited, start[None], goal[None], SETTINGS)
    assert walk.arrived[0]
    # With the limit check each step's interior is walked finely, q6 held on its limit
    # where both ends hold it: the slide along the limit still arrives.
    assert steer(limited, start[None], goal[None], CHECKED).arrived[0]
    points = np.stack(_walk_points(limited, start, goal))
    assert np.all(points[:, 5] <= 0.9) and np.sum(points[:, 5] == 0.9) > len(points) // 2
    assert_on_fibre(points, q0)
    # Recorded, the walk keeps the same points: each one where a walk of that many steps ends.
    recorded = steer(limited, start[None], goal[None], SETTINGS, record=True).points_rad[0]
    np.testing.assert_allclose(recorded, points[1:], rtol=0, atol=1e-12)


@pytest.mark.parametrize("obstacles", [False, True])
@pytest.mark.parametrize("model", ["iiwa14-position", "panda-position"])
def test_the_compiled_walks_take_the_numpy_loops_steps(model: str, obstacles: bool) -> None:
    """Walks between configurations of r = 4 fibres, self-collision checked (and a scene's
    obstacles of every shape) and the coaxial sets crossed as the service checks them: the
    compiled walks (`native.steer_walk`, taken for a serial chain) end where the numpy
    loop's do (the same fibre behind a plain callable), to 1e-10, and arrive alike, with
    and without the limit check (split over two threads: the same to the bit); an expired
    deadline stops them with the connect stage named.

    1e-10, not the single kernels' 1e-12: a walk is up to 100 steps, each projected until
    |e| is under 1e-4 rather than to convergence, so the last bits where C and numpy's
    LAPACK round differently are carried from step to step to the walk's end (measured:
    at most 1.1e-12 rad on a 2-core Intel Xeon, under 1e-12 on an AMD EPYC). A walk that
    took a different step would end orders of magnitude farther off."""
    served = load_model(REPO_MODELS_DIR / model, threads=1)
    rng = np.random.default_rng(41)
    arrived_any = stopped_any = False
    for served_space in served_position_spaces(
        served, 3, seed=42, scene=obstacle_scene() if obstacles else None
    ):
        space, through, nodes = served_space.compiled, served_space.numpy, served_space.nodes_rad
        a, b = rng.integers(len(nodes), size=(2, 60))
        for settings in (CHECKED, SETTINGS):  # with and without the limit check
            compiled = steer(space, nodes[a], nodes[b], settings)
            reference = steer(through, nodes[a], nodes[b], settings)
            assert compiled.arrived.tolist() == reference.arrived.tolist()
            np.testing.assert_allclose(compiled.q_end_rad, reference.q_end_rad, rtol=0, atol=1e-10)
        # The walks split over two threads: each is its own, to the bit.
        threaded = replace(space, fibre=replace(space.fibre, threads=2))
        split = steer(threaded, nodes[a], nodes[b], SETTINGS)
        assert split.arrived.tolist() == compiled.arrived.tolist()
        np.testing.assert_array_equal(split.q_end_rad, compiled.q_end_rad)
        arrived_any |= bool(compiled.arrived.any())
        stopped_any |= bool((~compiled.arrived).any())
    assert arrived_any and stopped_any
    with pytest.raises(DeadlineExceededError, match="connect"):
        steer(space, nodes[a], nodes[b], SETTINGS, deadline=Deadline.after(0.0))
