"""metrics: the measures against ground truth.

The toroidal nearest distance equals a brute-force joint-metric search, wraps across the
seam of a periodic joint and not of a limited one; errors are in the paper's units (% of
the reach and of pi) with mm and degrees beside them; stage medians are per span; recall by size
counts the exact components that hold a returned configuration; the wrong-count list names
the targets whose returned component count is not the exact one; the iiwa pose matcher
recognises exact, merged, split and missed components on answers built from the ground
truth itself.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.pipeline.components import summarise_all
from service.pipeline.joint_space import joint_distance
from service.pipeline.types import Component, SampleCounts, SmmResult, StageTimings
from tests.support.iiwa14_dh import LIMITS_RAD, iiwa14_pose
from training.evaluate.methods import MethodTarget
from training.evaluate.metrics import (
    errors_in_units,
    match_components,
    median_stage_ms,
    missed_components,
    nearest_distance,
    recall_by_size,
    wrong_count_targets,
)
from training.evaluate.references.iiwa14 import (
    pose_smm,
)
from training.evaluate.truth import Truth


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


def test_nearest_distance_wraps_a_periodic_joint_and_not_a_limited_one() -> None:
    query, data = np.array([[3.1, 3.1]]), np.array([[-3.1, 0.0], [0.0, -3.1]])
    wrapped_first = nearest_distance(query, data, np.array([True, False]))
    np.testing.assert_allclose(wrapped_first, np.hypot(2 * np.pi - 6.2, 3.1), atol=1e-12)
    limited = nearest_distance(query, data, np.array([False, False]))
    np.testing.assert_allclose(limited, np.hypot(6.2, 3.1), atol=1e-12)


def test_errors_are_in_percent_of_reach_and_of_pi_beside_mm_and_degrees() -> None:
    position_error_m = np.array([0.001, 0.003])  # mean 2 mm
    orientation_error_rad = np.array([np.pi / 100, np.pi / 100])  # 1 % of pi, 1.8 degrees
    pose = errors_in_units(position_error_m, orientation_error_rad, reach_m=2.0, pose=True)
    assert pose["e_p_pct"] == pytest.approx(0.1) and pose["mm"] == pytest.approx(2.0)
    assert pose["e_o_pct"] == pytest.approx(1.0) and pose["deg"] == pytest.approx(1.8)
    assert pose["e_pct"] == pytest.approx(0.55)  # the mean of the two
    position = errors_in_units(position_error_m, orientation_error_rad, reach_m=2.0, pose=False)
    assert position["e_o_pct"] is None and position["deg"] is None
    assert position["e_pct"] == position["e_p_pct"]
    empty = errors_in_units(np.zeros(0), np.zeros(0), reach_m=2.0, pose=True)
    assert set(empty.values()) == {None}


def test_median_stage_ms_is_the_median_per_span_to_a_hundredth() -> None:
    timings = [{"sample": 1.0, "total": 3.0}, {"sample": 2.0, "total": 9.0},
               {"sample": 10.004, "total": 4.0}]  # fmt: skip
    assert median_stage_ms(timings) == {"sample": 2.0, "total": 4.0}
    assert median_stage_ms(timings[2:]) == {"sample": 10.0, "total": 4.0}


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


def test_wrong_count_targets_lists_each_target_whose_count_is_not_the_exact_one() -> None:
    def answer(labels: np.ndarray | None) -> MethodTarget:
        k = 0 if labels is None else len(labels)
        return MethodTarget(
            np.zeros(3), np.zeros(3), np.zeros((k, 3)), np.zeros(k), np.zeros(k), labels, 4, 1.0
        )

    truth = Truth(points=np.zeros((1, 3)), count=2)
    answers = [answer(np.array([0, 1, 1])), answer(np.array([0, 0])), answer(np.array([], int))]
    assert [a.component_count for a in answers] == [2, 1, 0]
    assert wrong_count_targets(answers, [truth] * 3) == [
        {"index": 1, "expected": 2, "returned": 1},
        {"index": 2, "expected": 2, "returned": 0},
    ]
    assert answer(None).component_count is None  # the ODE trace labels no component
    assert wrong_count_targets([answer(None)], [truth]) == []


def _targets(count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    q = np.random.default_rng(seed).uniform(-LIMITS_RAD, LIMITS_RAD, (count, 7))
    return q, iiwa14_pose(q)


def _answer(pieces: list[np.ndarray]) -> SmmResult:
    components = [
        Component(
            q_rad=q, position_error_m=np.zeros(len(q)), orientation_error_rad=np.zeros(len(q))
        )
        for q in pieces
    ]
    accepted = sum(len(q) for q in pieces)
    return SmmResult(
        counts=SampleCounts(sampled=accepted, accepted=accepted, rejected_tolerance=0,
                            rejected_joint_limits=0),
        components=summarise_all(components, np.zeros(7, dtype=bool), None, None),
        timings=StageTimings(stage_ms={}, total_ms=0.0),
    )  # fmt: skip


def test_matcher_recognises_exact_merged_and_missed_components() -> None:
    _, poses = _targets(1, seed=3)
    reference = pose_smm(poses[0][:3, 3], poses[0][:3, :3])
    assert len(reference) >= 3
    every = [c.q_rad[::5] for c in reference]

    exact = match_components(_answer(every), reference)
    assert exact.exact and exact.found == len(reference) and exact.coverage_p95_rad < 0.05

    merged = match_components(_answer([np.concatenate(every[:2]), *every[2:]]), reference)
    assert merged.merged == 1 and merged.returned == len(reference) - 1 and not merged.exact

    missed = match_components(_answer(every[1:]), reference)
    assert missed.found == len(reference) - 1
    assert missed.missed_arc_rad == [round(reference[0].arc_length_rad, 3)]

    halves = np.array_split(every[0], 2)
    split = match_components(_answer([*halves, *every[1:]]), reference)
    assert split.split == 1 and not split.exact
