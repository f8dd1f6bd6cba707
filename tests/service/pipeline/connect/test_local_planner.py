"""local_planner: an edge holds when a path on the fibre joins its ends inside the limits,
and fails between different components however close (planar 3R closed form); the
compiled walks take the numpy loop's steps on the iiwa14's and Panda's r = 4 fibres."""

from dataclasses import replace

import numpy as np
import pytest

from service.errors import DeadlineExceededError
from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.connect.local_planner import PlannerSettings, edges_on_fibre, walk_on_fibre
from service.pipeline.deadline import Deadline
from service.pipeline.joint_space import JointLimits
from tests.service.pipeline.fibre_support import (
    fibre_space,
    obstacle_scene,
    planar_fibre,
    served_position_spaces,
)
from training.evaluate.references.planar3r import closed_form_smm

SETTINGS = PlannerSettings(delta_rad=0.05, lambda_=2.0, projection_tolerance=1e-4)
PERIODIC = np.ones(3, dtype=bool)
LOWER, UPPER = np.full(3, -np.pi), np.full(3, np.pi)
LIMITS = JointLimits(LOWER, UPPER, PERIODIC)


def test_points_of_one_loop_join_and_of_two_loops_do_not(planar3r: ServedModel) -> None:
    target = np.array([0.99, 0.0])  # just inside rho = 1: two loops, 0.34 rad apart at most
    loop_a, loop_b = closed_form_smm(target, phi_step_rad=0.001)
    space = fibre_space(planar_fibre(planar3r, target), LIMITS, ())
    # Along one loop: pairs about 0.3 and 1 rad apart (joint metric) join.
    same = edges_on_fibre(space, loop_a[[0, 0]], loop_a[[150, 500]], SETTINGS)
    assert same.tolist() == [True, True]
    # Across the loops: the nearest pairs, closer than points that do join, fail.
    a, b = loop_a[::5], loop_b[::5]
    d = np.linalg.norm(np.angle(np.exp(1j * (a[:, None, :] - b[None, :, :]))), axis=2)
    i, j = np.unravel_index(np.argsort(d, axis=None)[:5], d.shape)  # (A, B) joint metric
    assert d[i, j].max() < 0.4
    across = edges_on_fibre(space, a[i], b[j], SETTINGS)
    assert not across.any()


def test_an_edge_fails_when_the_path_leaves_the_limits(planar3r: ServedModel) -> None:
    target = np.array([1.5, 0.5])
    (loop,) = closed_form_smm(target, phi_step_rad=0.001)
    fibre = planar_fibre(planar3r, target)
    # A stretch of the loop over which one joint rises and falls again: a limit just under
    # its peak leaves both ends inside but cuts the only path between them.
    joint, before, peak, after = _bump(loop)
    a, b = loop[before], loop[after]
    q = np.unwrap(loop[:, joint])
    limited = np.ones(3, dtype=bool)
    limited[joint] = False
    upper = UPPER.copy()
    upper[joint] = loop[peak, joint] - 0.005
    assert loop[before, joint] < upper[joint] and loop[after, joint] < upper[joint]
    assert q[peak] - 0.005 > max(q[before], q[after])
    free = edges_on_fibre(fibre_space(fibre, LIMITS, ()), a[None], b[None], SETTINGS)
    cut = fibre_space(fibre, JointLimits(LOWER, upper, limited), ())
    blocked = edges_on_fibre(cut, a[None], b[None], SETTINGS)
    assert free.tolist() == [True]
    assert blocked.tolist() == [False]


def _bump(loop: np.ndarray) -> tuple[int, int, int, int]:
    """(joint, before, peak, after): a local maximum of a joint along the loop, inside
    (-3, 3), with the joint 0.05 rad lower at `before` and `after` within 400 points."""
    for joint in range(3):
        q = loop[:, joint]
        for peak in range(400, len(q) - 400):
            window = q[peak - 400 : peak + 401]
            if abs(q[peak]) < 3.0 and q[peak] == window.max() and np.ptp(window) < 1.0:
                before = peak - int(np.argmax(q[peak::-1] < q[peak] - 0.05))
                after = peak + int(np.argmax(q[peak:] < q[peak] - 0.05))
                if before < peak < after:
                    return joint, before, peak, after
    raise AssertionError("no bump found")


SERVED = PlannerSettings(delta_rad=0.1, lambda_=2.0, projection_tolerance=1e-4)
LONG_STEPS = PlannerSettings(delta_rad=0.5, lambda_=3.0, projection_tolerance=1e-4)


@pytest.mark.parametrize("obstacles", [False, True])
@pytest.mark.parametrize("model", ["iiwa14-position", "panda-position"])
def test_the_compiled_walks_take_the_numpy_loops_steps(model: str, obstacles: bool) -> None:
    """Edges between configurations on r = 4 fibres, self-collision checked (and a scene's
    obstacles of every shape) and the coaxial sets crossed as the service checks them: the
    compiled walks (`native.projected_walk`, taken for a serial chain) reach the same ends
    and step through the same points (1e-12) as the numpy loop (the same fibre behind a
    plain callable, whose steps are numpy's), and the same to the bit with the edges split
    over two threads; an expired deadline stops them with the connect stage named."""
    served = load_model(REPO_MODELS_DIR / model, threads=1)
    rng = np.random.default_rng(31)
    reached_any = failed_any = False
    for served_space in served_position_spaces(
        served, 3, seed=32, scene=obstacle_scene() if obstacles else None
    ):
        space, through, nodes = served_space.compiled, served_space.numpy, served_space.nodes_rad
        a, b = rng.integers(len(nodes), size=(2, 200))
        # The service's steps, and steps of 0.5 rad, which some coaxial crossings refuse.
        for settings in (SERVED, LONG_STEPS):
            compiled = walk_on_fibre(space, nodes[a], nodes[b], settings)
            reference = walk_on_fibre(through, nodes[a], nodes[b], settings)
            assert compiled.reached.tolist() == reference.reached.tolist()
            # The edges split over two threads: each walk is its own, to the bit.
            threaded = replace(space, fibre=replace(space.fibre, threads=2))
            split = walk_on_fibre(threaded, nodes[a], nodes[b], settings)
            assert split.reached.tolist() == compiled.reached.tolist()
            for mine, theirs in zip(split.points_rad, compiled.points_rad, strict=True):
                np.testing.assert_array_equal(mine, theirs)
            for mine, theirs in zip(compiled.points_rad, reference.points_rad, strict=True):
                np.testing.assert_allclose(mine, theirs, rtol=0, atol=1e-12)
            reached_any |= bool(compiled.reached.any())
            failed_any |= bool((~compiled.reached & (a != b)).any())
    assert reached_any and failed_any
    with pytest.raises(DeadlineExceededError, match="connect"):
        walk_on_fibre(space, nodes[a], nodes[b], SERVED, deadline=Deadline.after(0.0))
