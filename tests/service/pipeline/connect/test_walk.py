"""The trace's walk, compiled (`native.walk`), takes the numpy walk's steps: on fibres of
the iiwa14 and Panda poses and the planar 3R, uniform targets and one next to a singular
value (the iiwa's elbow almost straight, where the twins test acts), the fronts move to
the same points (1e-12, with the errors, Jacobians and tangents measured there), meet
the same partners and chain into the same curves; the output rows grow as needed and
lose none; a walk past its deadline stops and the trace raises the deadline error
naming the connect stage."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from service.errors import DeadlineExceededError
from service.manifest import REPO_MODELS_DIR
from service.models.chain import SerialChainKinematics
from service.models.registry import load_model
from service.pipeline import native
from service.pipeline.connect.settings import trace_settings
from service.pipeline.connect.trace.points import Evaluated
from service.pipeline.connect.trace.seeds import spread_seeds
from service.pipeline.connect.trace.walk import MEET_FACTOR, TWIN_OFFSET, TWIN_SIGMA, walk_fronts
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import evaluate, project, unit_tangent
from tests.service.pipeline.fibre_support import pose_fibre
from tests.support.numpy_kernels import NumpyStepsKinematics
from training.evaluate.targets import uniform_configurations


@pytest.mark.parametrize("model", ["iiwa14-pose", "panda-pose", "planar3r-position"])
def test_walk_takes_the_numpy_walks_steps(model: str) -> None:
    """The trace's fronts, compiled, move to the points the numpy loop moves them to, in
    the same order, meet the same partners and chain into the same curves, on fibres of
    uniform targets and of one next to a singular value (the iiwa's elbow almost
    straight, where the twins test may act): points, errors, Jacobians and tangents to
    1e-12, with the output rows grown from a single step's worth."""
    served = load_model(REPO_MODELS_DIR / model, threads=1)
    settings = trace_settings(served.manifest.defaults.connectivity)
    limits = served.limits
    q_targets = list(uniform_configurations(limits, 4, seed=25))
    if model == "iiwa14-pose":
        q_targets.append(np.array([0.3, 0.8, -0.2, 0.004, 0.5, -0.6, 0.1]))
    for q_target in q_targets:
        fibre = pose_fibre(served, q_target)
        assert isinstance(fibre.kinematics, SerialChainKinematics) and fibre.chain is not None
        through = replace(fibre, kinematics=NumpyStepsKinematics(fibre.kinematics))  # numpy steps
        assert through.chain is None
        q_near = q_target + np.random.default_rng(26).normal(scale=0.3, size=(400, len(q_target)))
        exact = project(fibre, q_near, 30)
        start = evaluate(fibre, spread_seeds(exact.q_rad[exact.error_norm < 1e-8], 1.0))
        seeds = Evaluated.of(start, unit_tangent(start.jacobian))
        compiled = walk_fronts(fibre, seeds, settings, NO_DEADLINE)
        reference = walk_fronts(through, seeds, settings, NO_DEADLINE)
        for a, b in zip(
            (compiled[0].q_rad, compiled[0].error, compiled[0].jacobian, compiled[0].tangent),
            (reference[0].q_rad, reference[0].error, reference[0].jacobian, reference[0].tangent),
            strict=True,
        ):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
        for ours, theirs in zip(
            (compiled[1].rows, compiled[1].first, compiled[1].closed),
            (reference[1].rows, reference[1].first, reference[1].closed),
            strict=True,
        ):
            np.testing.assert_array_equal(ours, theirs)
        assert compiled[2] == reference[2]
        fronts = 2 * len(seeds)
        q = np.repeat(seeds.q_rad, 2, axis=0)
        t = np.repeat(seeds.tangent, 2, axis=0) * np.tile([1.0, -1.0], len(seeds))[:, None]
        target = fibre.target
        rules = native.WalkRules(
            settings.step_rad, settings.corrector_iterations, settings.max_steps,
            MEET_FACTOR, TWIN_SIGMA, TWIN_OFFSET,
        )  # fmt: skip
        chain_of = fibre.kinematics
        walked = native.walk(
            chain_of.fixed, chain_of.tip, fibre.task.position_axes, target.position_m,
            target.rotation, q, t, np.repeat(seeds.jacobian, 2, axis=0), rules, fibre.damping,
            np.inf, capacity=fronts,
        )  # fmt: skip
        assert len(walked.front) > fronts  # it grew its rows, and lost none
        np.testing.assert_array_equal(walked.q_rad, compiled[0].q_rad[len(seeds) :])


def test_walk_stops_at_the_deadline() -> None:
    """A walk whose deadline has passed stops before its first step, and the trace
    raises the deadline error naming the connect stage."""
    served = load_model(REPO_MODELS_DIR / "planar3r-position", threads=1)
    settings = trace_settings(served.manifest.defaults.connectivity)
    fibre = pose_fibre(served, np.array([0.3, 0.9, -0.4]))
    start = evaluate(fibre, project(fibre, np.array([[0.3, 0.9, -0.4]]), 3).q_rad)
    seeds = Evaluated.of(start, unit_tangent(start.jacobian))
    passed = Deadline(budget_s=1.0, expires_at_s=time.monotonic() - 1.0)
    with pytest.raises(DeadlineExceededError, match="connect"):
        walk_fronts(fibre, seeds, settings, passed)
