"""training.evaluate.report and .plots: metrics against ground truth, on a small run.

The toroidal nearest-distance helper equals a brute-force joint-metric search; a small
planar report finds the closed-form component counts, returns exact configurations within
the limits, covers the closed-form SMM and writes both tables; the count-accuracy plot
bins targets by distance as a hand count does; recall by size counts the exact
components that hold a returned configuration; the 4-D ground truth has components and
falls back to the generating configuration where the fibre is thinner than its grid.
"""

from __future__ import annotations

import numpy as np

from service.config import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.joint_space import joint_distance
from training.evaluate.plots import count_accuracy_by_distance
from training.evaluate.report import (
    MethodTarget,
    Truth,
    evaluate,
    ground_truth,
    markdown,
    missed_components,
    nearest_distance,
    recall_by_size,
)


def test_nearest_distance_equals_brute_force_on_mixed_joints() -> None:
    rng = np.random.default_rng(0)
    periodic = np.array([True, False, True])
    data = rng.uniform(-np.pi, np.pi, (300, 3))
    query = rng.uniform(-np.pi, np.pi, (50, 3))
    brute = np.array([joint_distance(data, q, periodic).min() for q in query])
    np.testing.assert_allclose(nearest_distance(query, data, periodic), brute, atol=1e-12)
    # Across the seam of a periodic joint the nearest point is the wrapped one.
    near_seam = nearest_distance(
        np.array([[3.1, 0.0, 0.0]]), np.array([[-3.1, 0.0, 0.0]]), periodic
    )
    np.testing.assert_allclose(near_seam, 2 * np.pi - 6.2, atol=1e-12)
    assert np.isinf(nearest_distance(query, np.zeros((0, 3)), periodic)).all()


def test_small_planar_report_meets_the_closed_form(planar3r: ServedModel) -> None:
    report = evaluate(planar3r, num_targets=3, seed=1, num_samples=400)
    methods = report["methods"]
    assert isinstance(methods, dict)
    served = methods["FM + DLS"]
    assert served["returned"]["mm"] < 1e-3  # every returned configuration within 1e-6 m
    assert served["limit_violations"] == 0
    assert served["component_count"]["right"] == 1.0
    assert served["coverage_rad"]["p95"] < 0.1
    assert methods["FM"]["raw"]["mm"] > 1.0  # the raw flow is millimetres off
    assert methods["ODE"]["raw"]["mm"] < 1e-6  # RK5 drift only
    text = markdown("planar3r-position", report)
    assert "| FM + DLS |" in text and "| random-restart DLS |" in text and "count right" in text


def test_count_accuracy_bins_targets_by_distance() -> None:
    distance = np.array([0.1, 0.2, 0.6, 0.7, 0.8, 1.0])
    right = np.array([True, False, True, True, False, True])
    fraction, totals = count_accuracy_by_distance(distance, right, np.array([0.0, 0.5, 1.0]))
    np.testing.assert_array_equal(totals, [2, 4])  # the last edge belongs to the last bin
    np.testing.assert_allclose(fraction, [0.5, 0.75])


def test_recall_by_size_counts_components_holding_an_answer() -> None:
    pieces = [np.full((5, 7), 0.0), np.full((5, 7), 1.0), np.full((5, 7), 2.0)]
    for i, piece in enumerate(pieces):
        piece[:, 0] += np.linspace(0.0, 0.1, 5) + 0.01 * i
    truth = Truth(
        points=np.concatenate(pieces),
        count=3,
        point_component=np.repeat([0, 1, 2], 5),
        size=np.array([0.3, 1.0, 3.0]),
    )
    returned = np.concatenate([pieces[0][:2], pieces[2][3:]]) + 1e-9  # components 0 and 2
    answer = MethodTarget(
        np.zeros(3), np.zeros(3), returned, np.zeros(4), np.zeros(4), np.zeros(4), 4, 1.0
    )
    buckets = recall_by_size([answer], [truth])
    assert [b["components"] for b in buckets] == [1, 1, 1]
    assert [b["recall"] for b in buckets] == [1.0, 0.0, 1.0]
    # The 1.0 rad component is missed; the 0.3 rad one is below the listed sizes anyway.
    assert missed_components([answer], [truth]) == [{"index": 0, "sizes": [1.0]}]


def test_position_ground_truth_has_components_and_stands_in_at_the_workspace_edge() -> None:
    model = load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)
    inside = ground_truth(model, np.array([0.3, 0.8, 0.2, -1.2, 0.4, 0.9, 0.1]), seed=0)
    assert inside.count >= 1 and inside.size is not None and len(inside.points) > 1000
    # The arm straight out: the target is at full reach, the fibre is thinner than any
    # grid, and the generating configuration stands for it as one component.
    straight = np.array([0.3, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    edge = ground_truth(model, straight, seed=0)
    assert edge.count == 1
    np.testing.assert_array_equal(edge.points, straight[None])
