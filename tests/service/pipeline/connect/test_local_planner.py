"""local_planner: an edge holds when a path on the fibre joins its ends inside the limits,
and fails between different components however close (planar 3R closed form), and across
a sliver outside the limits narrower than a step only with the limit check; the compiled
walks take the numpy loop's steps on the iiwa14's and Panda's r = 4 fibres."""

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
    bump_of,
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
    joint, before, peak, after = bump_of(loop)
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


def test_a_step_over_a_sliver_outside_the_limits_holds_only_without_the_limit_check(
    planar3r: ServedModel,
) -> None:
    """A limit 5 mrad under a joint's peak cuts the closed-form loop between two points
    either side of the peak. A walk whose step is longer than the whole stretch takes it as
    one last hop, checked where it lands (OMPL's check), and joins across the cut; with
    `limit_check_rad` the hop's interior is checked at that spacing and the edge fails,
    while the same walk on the uncut loop still holds."""
    target = np.array([1.5, 0.5])
    (loop,) = closed_form_smm(target, phi_step_rad=0.001)
    fibre = planar_fibre(planar3r, target)
    joint, before, peak, after = bump_of(loop)
    a, b = loop[before], loop[after]
    upper = UPPER.copy()
    upper[joint] = loop[peak, joint] - 0.005
    limited = np.ones(3, dtype=bool)
    limited[joint] = False
    cut = fibre_space(fibre, JointLimits(LOWER, upper, limited), ())
    uncut = fibre_space(fibre, LIMITS, ())
    one_hop = PlannerSettings(delta_rad=1.5, lambda_=2.0, projection_tolerance=1e-4)
    checked = replace(one_hop, limit_check_rad=0.01)
    assert np.linalg.norm(b - a) < one_hop.delta_rad  # the whole edge is one hop
    assert edges_on_fibre(cut, a[None], b[None], one_hop).tolist() == [True]
    assert edges_on_fibre(cut, a[None], b[None], checked).tolist() == [False]
    assert edges_on_fibre(uncut, a[None], b[None], checked).tolist() == [True]


SERVED = PlannerSettings(delta_rad=0.1, lambda_=2.0, projection_tolerance=1e-4)
LONG_STEPS = PlannerSettings(delta_rad=0.5, lambda_=3.0, projection_tolerance=1e-4)
CHECKED = replace(LONG_STEPS, limit_check_rad=0.02)  # each step's interior checked too


@pytest.mark.parametrize("obstacles", [False, True])
@pytest.mark.parametrize("model", ["iiwa14-position", "panda-position"])
def test_the_compiled_walks_take_the_numpy_loops_steps(model: str, obstacles: bool) -> None:
    """Edges between configurations on r = 4 fibres, self-collision checked (and a scene's
    obstacles of every shape) and the coaxial sets crossed as the service checks them: the
    compiled walks (`native.projected_walk`, taken for a serial chain) reach the same ends
    and step through the same points (1e-12) as the numpy loop (the same fibre behind a
    plain callable, whose steps are numpy's), and the same to the bit with the edges split
    over two threads; an expired deadline stops them with the connect stage named. With
    the limit check (CHECKED) they agree too."""
    served = load_model(REPO_MODELS_DIR / model, threads=1)
    rng = np.random.default_rng(31)
    reached_any = failed_any = False
    for served_space in served_position_spaces(
        served, 3, seed=32, scene=obstacle_scene() if obstacles else None
    ):
        space, through, nodes = served_space.compiled, served_space.numpy, served_space.nodes_rad
        a, b = rng.integers(len(nodes), size=(2, 200))
        # The service's steps, and steps of 0.5 rad, which some coaxial crossings refuse,
        # without and with the limit check.
        for settings in (SERVED, LONG_STEPS, CHECKED):
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


def test_the_limit_check_refuses_only_steps_a_walk_as_fine_as_it_refuses() -> None:
    """Edges between configurations of the iiwa14's r = 4 fibres at steps of 0.5 rad: with
    the limit check every edge that holds also holds without it, it refuses some that hold
    without it, and each of those a plain walk at the check's own 0.02 rad steps refuses
    too (the interior the long steps passed over is not there to walk)."""
    served = load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)
    rng = np.random.default_rng(31)
    fine = PlannerSettings(delta_rad=0.02, lambda_=3.0, projection_tolerance=1e-4)
    refused = 0
    for served_space in served_position_spaces(served, 3, seed=32):
        space, nodes = served_space.compiled, served_space.nodes_rad
        a, b = rng.integers(len(nodes), size=(2, 200))
        unchecked = edges_on_fibre(space, nodes[a], nodes[b], LONG_STEPS)
        checked = edges_on_fibre(space, nodes[a], nodes[b], CHECKED)
        assert not (checked & ~unchecked).any()
        only = np.flatnonzero(unchecked & ~checked)
        assert not edges_on_fibre(space, nodes[a[only]], nodes[b[only]], fine).any()
        refused += len(only)
    assert refused > 0
