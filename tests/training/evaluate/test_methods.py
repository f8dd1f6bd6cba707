"""methods: each method's answer to one target, as the report measures it.

The service's answer (FM + DLS) returns exact, labelled configurations, each component's
path points among them, and the flow's raw samples beside them; the FM row is those raw
samples alone; random-restart DLS keeps only accepted solutions and groups them with the
service's connect stage; the ODE trace stays on the fibre and has no component labels.
The path gap measure wraps a periodic joint and closes a loop.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.correction import task_error_norms
from service.pipeline.joint_space import JointLimits, joint_distance, wrap_periodic
from service.pipeline.types import ComponentPath
from training.evaluate.baselines.restart_dls import random_restart_dls
from training.evaluate.methods import (
    flow_target,
    ode_target,
    path_max_gap_rad,
    raw_samples_target,
    reference_target,
    restart_target,
    returned_points,
)
from training.kinematics import load_chain
from training.robots import robot_spec

Q_TARGET_RAD = np.array([0.4, 2.2, 1.1])  # planar 3R, rho about 0.87 m: two loops


def _path(q: list[list[float]], closed: bool) -> ComponentPath:
    points = np.array(q)
    zeros = np.zeros(len(points))
    return ComponentPath(points, zeros, zeros, closed, arc_length_rad=0.0)


def test_path_gap_wraps_a_periodic_joint_and_closes_a_loop() -> None:
    periodic = np.array([True, False])
    open_path = _path([[3.1, 0.0], [-3.1, 0.0], [-3.0, 0.0]], closed=False)
    # Across the seam 3.1 -> -3.1 is 2 pi - 6.2 = 0.083 rad; the largest step is 0.1.
    assert path_max_gap_rad([open_path], periodic) == pytest.approx(0.1)
    # Closed, the step back from -3.0 to 3.1 counts too: 2 pi - 6.1 = 0.183 rad.
    loop = _path([[3.1, 0.0], [-3.1, 0.0], [-3.0, 0.0]], closed=True)
    assert path_max_gap_rad([loop], periodic) == pytest.approx(2 * np.pi - 6.1)
    # Not periodic, the seam is a jump of 6.2 rad.
    assert path_max_gap_rad([open_path], np.array([False, False])) == pytest.approx(6.2)
    # Over several paths, the largest; none at all: None.
    far = _path([[0.0, 0.0], [0.0, 0.5]], closed=False)
    assert path_max_gap_rad([open_path, far], periodic) == pytest.approx(0.5)
    assert path_max_gap_rad([], periodic) is None


def test_returned_points_label_path_points_so_a_size_0_component_counts() -> None:
    samples = np.ones((2, 2))
    returned = returned_points(
        [(samples, None), (np.zeros((0, 2)), _path([[0.0, 0.0], [0.1, 0.0]], closed=False))],
        num_joints=2,
    )
    np.testing.assert_array_equal(returned.labels, [0, 0, 1, 1])
    np.testing.assert_array_equal(returned.on_path, [False, False, True, True])
    assert returned.q_rad.shape == (4, 2) and [i for i, _ in returned.paths] == [1]
    empty = returned_points([], num_joints=3)
    assert empty.q_rad.shape == (0, 3) and len(empty.labels) == len(empty.on_path) == 0


def test_the_service_answer_is_exact_labelled_and_the_fm_row_is_its_raw_samples(
    planar3r: ServedModel,
) -> None:
    answer = flow_target(planar3r, Q_TARGET_RAD, 300, seed=0)
    # The keep rate's denominator is what the pipeline drew: the planar 3R draws rounds of
    # 128 and stops after the second (both loops traced from the first); the FM row is
    # the flow's num_samples raw samples.
    rounds = planar3r.manifest.defaults.sampler.round_samples
    assert rounds is not None and answer.sampled == 2 * rounds
    assert len(answer.raw_position_m) == 300
    assert len(answer.returned) > 0 and answer.labels is not None
    assert len(answer.labels) == len(answer.returned) == len(answer.returned_position_m)
    assert answer.returned_position_m.max() <= planar3r.manifest.defaults.tolerance_position_m
    assert answer.stage_ms is not None and answer.time_ms == answer.stage_ms["total"]
    assert "connect" in answer.stage_ms and "cluster" not in answer.stage_ms
    # r = 1: every component comes with its path, whose points are returned and labelled.
    assert answer.on_path is not None and answer.path_points > 0
    assert answer.component_count == 2 and len(answer.paths) == 2
    for index, path in answer.paths:
        np.testing.assert_array_equal(answer.returned[answer.on_path & (answer.labels == index)],
                                      path.q_rad)  # fmt: skip
    assert answer.kept + answer.path_points == len(answer.returned) and answer.kept <= 300
    assert answer.path_max_gap_rad is not None and answer.path_max_gap_rad < 0.2
    assert answer.near_singular is False

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


def test_restart_components_come_from_the_connect_stage(planar3r: ServedModel) -> None:
    robot = robot_spec(planar3r.manifest.robot)
    chain = load_chain(REPO_MODELS_DIR / robot.urdf, robot.end_effector_link)
    restart = restart_target(planar3r, chain, Q_TARGET_RAD, 100, seed=0)
    limits = planar3r.limits
    spacing = planar3r.manifest.defaults.connectivity.path_spacing_rad
    assert restart.labels is not None and restart.on_path is not None
    # The two loops traced whole, each with its path; every accepted solution lies on
    # the path of its own component (within the path spacing), as connect assigns it.
    assert restart.component_count == 2 and [i for i, _ in restart.paths] == [0, 1]
    kept, kept_labels = restart.returned[~restart.on_path], restart.labels[~restart.on_path]
    assert len(kept) > 0
    for q, label in zip(kept, kept_labels, strict=True):
        distance = [
            joint_distance(path.q_rad, q, limits.periodic).min() for _, path in restart.paths
        ]
        assert distance[label] <= spacing and int(np.argmin(distance)) == label
    # Its time includes accept and connect.
    stages = restart.stage_ms
    assert stages is not None and stages["connect"] > 0
    assert restart.time_ms == pytest.approx(stages["solve"] + stages["accept"] + stages["connect"])
    assert restart.near_singular is False


def test_restart_dls_on_a_4d_fibre_is_pulled_into_the_limits_as_the_service_is() -> None:
    """On the iiwa14 position (r = 4) the baseline takes the service's stages after its
    correction: solutions within tolerance but past a limit are pulled into the limits,
    so it keeps at least the solutions that were inside them, and more where the pull
    brought some in; each kept one is within tolerance and the limits."""
    model = load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)
    manifest = model.manifest
    robot = robot_spec(manifest.robot)
    chain = load_chain(REPO_MODELS_DIR / robot.urdf, robot.end_effector_link, robot.base_link)
    limits = JointLimits.of(manifest.joints)
    q_target = np.array([0.3, 0.8, -0.4, -1.2, 0.5, 1.0, 0.2])
    target, position_m = reference_target(model, q_target)
    solutions = random_restart_dls(
        chain, manifest.joints, manifest.task, position_m, None, 300, seed=3
    )
    q = wrap_periodic(solutions.q_rad.astype(np.float64), limits.periodic)
    error_m, _ = task_error_norms(model.kinematics(q), target, manifest.task)
    tolerance_m = manifest.defaults.tolerance_position_m
    inside = np.all((q >= limits.lower_rad) & (q <= limits.upper_rad), axis=1)
    within = error_m <= tolerance_m
    restart = restart_target(model, chain, q_target, 300, seed=3)
    assert (within & ~inside).any()  # the case the pull is for: some past a limit
    assert restart.kept > int((within & inside).sum())
    kept = restart.returned[~restart.on_path] if restart.on_path is not None else restart.returned
    assert np.all((kept >= limits.lower_rad - 1e-12) & (kept <= limits.upper_rad + 1e-12))
    stages = restart.stage_ms
    assert stages is not None and stages["correct"] > 0
    assert restart.time_ms == pytest.approx(sum(stages.values()) - stages["total"])
