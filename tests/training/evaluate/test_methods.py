"""methods: each method's answer to one target, as the report measures it.

The service's answer (FM + DLS) returns exact, labelled configurations and the flow's raw
samples beside them; the FM row is those raw samples alone; random-restart DLS keeps only
accepted solutions; the ODE trace stays on the fibre and has no component labels.
"""

from __future__ import annotations

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel
from training.evaluate.methods import (
    flow_target,
    ode_target,
    raw_samples_target,
    reference_target,
    restart_target,
)
from training.kinematics import load_chain
from training.robots import robot_spec

Q_TARGET_RAD = np.array([0.4, 2.2, 1.1])  # planar 3R, rho about 1.5 m: one component


def test_the_service_answer_is_exact_labelled_and_the_fm_row_is_its_raw_samples(
    planar3r: ServedModel,
) -> None:
    answer = flow_target(planar3r, Q_TARGET_RAD, 300, seed=0)
    assert answer.sampled == 300 and len(answer.raw_position_m) == 300
    assert len(answer.returned) > 0 and answer.labels is not None
    assert len(answer.labels) == len(answer.returned) == len(answer.returned_position_m)
    assert answer.returned_position_m.max() <= planar3r.manifest.defaults.tolerance_position_m
    assert answer.stage_ms is not None and answer.time_ms == answer.stage_ms["total"]

    flow_only = raw_samples_target(answer)
    assert flow_only.returned.shape == (0, 3) and flow_only.labels is None
    np.testing.assert_array_equal(flow_only.returned_position_m, answer.raw_position_m)
    assert flow_only.sampled == 300 and flow_only.time_ms == answer.stage_ms["sample"]


def test_the_baselines_return_configurations_on_the_target(planar3r: ServedModel) -> None:
    target, position_m = reference_target(planar3r, Q_TARGET_RAD)
    np.testing.assert_allclose(target.position_m, position_m[:2])
    robot = robot_spec(planar3r.manifest.robot)
    chain = load_chain(REPO_MODELS_DIR / robot.urdf, robot.end_effector_link)
    restart = restart_target(planar3r, chain, Q_TARGET_RAD, 100, seed=0)
    assert len(restart.returned) > 0 and restart.labels is not None
    assert restart.returned_position_m.max() <= planar3r.manifest.defaults.tolerance_position_m
    trace = ode_target(planar3r, Q_TARGET_RAD)
    assert trace.labels is None and trace.sampled == len(trace.returned) > 10
    assert trace.returned_position_m.max() < 1e-6
