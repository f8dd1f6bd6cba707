"""metrics: the measures against ground truth.

The toroidal nearest distance equals a brute-force joint-metric search, wraps across the
seam of a periodic joint and not of a limited one; errors are in the paper's units (% of
the reach and of pi) with mm and degrees beside them; stage medians and 95th percentiles
are per span; recall by size counts the exact components that hold a returned
configuration; splits, merges and extra-small components are counted as
COUNT_RIGHT_DEFINITION says (only exact components of at least 1 % of a 4-D fibre
count), each configuration in the component of its nearest label node where the 4-D
reference gives its every node (else of its nearest exact point), and count right needs
the count, no split and no merge; the wrong-count list names the targets whose count is
not right; the summary checks the returned paths; the iiwa pose matcher recognises
exact, merged, split and missed components on answers built from the ground truth
itself, path points included.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from service.models.registry import ServedModel
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.components import summarise_all
from service.pipeline.joint_space import JointLimits, joint_distance
from service.pipeline.types import (
    Component,
    ComponentPath,
    FibreStructure,
    SampleCounts,
    SmmResult,
    StageTimings,
)
from training.evaluate.methods import MethodTarget
from training.evaluate.metrics import (
    Agreement,
    component_agreement,
    errors_in_units,
    exact_labels,
    match_components,
    median_stage_ms,
    missed_components,
    nearest_distance,
    p95_stage_ms,
    recall_by_size,
    regular_targets,
    summarise,
    wrong_count_targets,
)
from training.evaluate.references.iiwa14 import (
    LIMITS_RAD,
    pose_smm,
)
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.truth import SHARE_BUCKETS, Truth


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


def test_p95_stage_ms_is_the_95th_percentile_per_span() -> None:
    # connect 0, 5, ..., 100 ms over 21 targets: the 95th percentile is 95 ms; a slow
    # tail in one span does not move another's.
    timings = [{"connect": 5.0 * i, "total": 10.0} for i in range(21)]
    timings[-1]["total"] = 1000.0
    assert p95_stage_ms(timings) == {"connect": 95.0, "total": 10.0}
    assert p95_stage_ms(timings[:1]) == {"connect": 0.0, "total": 10.0}
    # Between two targets: linear interpolation, to a hundredth.
    assert p95_stage_ms([{"connect": 1.0}, {"connect": 2.0}]) == {"connect": 1.95}


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


# The iiwa's joints, none periodic (summarise_all reads only which are).
IIWA_LIMITS = JointLimits(-LIMITS_RAD, LIMITS_RAD, np.zeros(7, dtype=bool))


def _answer(pieces: list[np.ndarray], paths: list[np.ndarray] | None = None) -> SmmResult:
    """Components with the given members and (optionally) the given paths."""
    paths = paths or []
    components = [
        Component(
            q_rad=q, position_error_m=np.zeros(len(q)), orientation_error_rad=np.zeros(len(q))
        )
        for q in pieces
    ] + [
        Component(
            q_rad=np.zeros((0, 7)), position_error_m=np.zeros(0),
            orientation_error_rad=np.zeros(0),
            path=ComponentPath(q, np.zeros(len(q)), np.zeros(len(q)), False, 0.0),
        )
        for q in paths
    ]  # fmt: skip
    accepted = sum(len(q) for q in pieces)
    return SmmResult(
        counts=SampleCounts(sampled=accepted, accepted=accepted, rejected_tolerance=0,
                            rejected_joint_limits=0, rejected_collision=0),
        components=summarise_all(components, IIWA_LIMITS, CollisionCheck.none(), None, None,
                                 True),
        structure=FibreStructure(near_singular=False, min_singular_value=None, traced=True),
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

    # A component found by tracing alone (no accepted sample) is found through its path.
    traced = match_components(_answer(every[1:], paths=[reference[0].q_rad]), reference)
    assert traced.exact and traced.returned == len(reference)


def _exact_truth(sizes: list[float], count: int, four_d: bool) -> Truth:
    """Exact components at q1 = 0, 1, 2, ...: five points each along q1, the rest 0."""
    points = np.zeros((5 * len(sizes), 7))
    points[:, 0] = np.repeat(np.arange(len(sizes)), 5) + np.tile(
        np.linspace(0.0, 0.1, 5), len(sizes)
    )
    if not four_d:
        return Truth(points, count, np.repeat(np.arange(len(sizes)), 5), np.array(sizes))
    return Truth(points, count, np.repeat(np.arange(len(sizes)), 5), np.array(sizes),
                 size_edges=SHARE_BUCKETS, membership_joints=6)  # fmt: skip


def _on(groups: list[list[int]], on_path: np.ndarray | None = None) -> MethodTarget:
    """Returned component j: one configuration on each exact component in groups[j]."""
    returned = np.zeros((sum(len(g) for g in groups), 7))
    returned[:, 0] = np.concatenate([g for g in groups if g] or [[]]) + 0.05
    returned[:, 6] = 2.0  # q7 does not decide membership in the 4-D fibre
    labels = np.concatenate([np.full(len(g), j) for j, g in enumerate(groups)])
    k = len(returned)
    return MethodTarget(np.zeros(k), np.zeros(k), returned, np.zeros(k), np.zeros(k), labels,
                        k, 1.0, on_path=on_path)  # fmt: skip


# Two exact components above 1 % of the fibre (A, B), two below (C, D): the count is 2.
FOUR_D = _exact_truth([0.6, 0.39, 0.005, 0.005], count=2, four_d=True)


@pytest.mark.parametrize(
    ("groups", "expected"),
    [
        ([[0], [1]], Agreement(2, 2, splits=0, merges=0, extra_small=0)),
        ([[0], [0], [1]], Agreement(3, 2, splits=1, merges=0, extra_small=0)),
        ([[0, 1]], Agreement(1, 2, splits=0, merges=1, extra_small=0)),
        # A returned component only on a small exact one is extra small, not counted.
        ([[0], [1], [2]], Agreement(2, 2, splits=0, merges=0, extra_small=1)),
        # A small exact component beside a counted one is no merge ...
        ([[0, 2], [1]], Agreement(2, 2, splits=0, merges=0, extra_small=0)),
        # ... nor is a small exact component spread over two returned ones a split.
        ([[0], [1], [2], [2]], Agreement(2, 2, splits=0, merges=0, extra_small=2)),
        ([[0], [1, 2], [1]], Agreement(3, 2, splits=1, merges=0, extra_small=0)),
        ([[0], [2, 3]], Agreement(1, 2, splits=0, merges=0, extra_small=1)),
    ],
)
def test_splits_merges_and_extra_small_components_of_a_4d_fibre(
    groups: list[list[int]], expected: Agreement
) -> None:
    assert component_agreement(_on(groups), FOUR_D) == expected


def test_count_right_needs_the_count_and_no_split_and_no_merge() -> None:
    assert component_agreement(_on([[0], [1]]), FOUR_D).right  # type: ignore[union-attr]
    assert component_agreement(_on([[0], [1], [2]]), FOUR_D).right  # type: ignore[union-attr]
    # The right number of components, but one lies on A and B (a merge) and B is
    # spread over both (a split): not right.
    wrong = component_agreement(_on([[0, 1], [1]]), FOUR_D)
    assert wrong == Agreement(2, 2, splits=1, merges=1, extra_small=0) and not wrong.right
    # 1-D (arc-length buckets): every exact component counts, however short.
    one_d = _exact_truth([3.0, 1.0, 0.1, 0.1], count=4, four_d=False)
    assert component_agreement(_on([[0], [1], [2], [3]]), one_d).right  # type: ignore[union-attr]
    short_merged = component_agreement(_on([[0], [1], [2, 3]]), one_d)
    assert short_merged == Agreement(3, 4, splits=0, merges=1, extra_small=0)
    # No exact component labels (planar 3R): the count alone, against the closed form.
    planar = Truth(points=np.zeros((1, 7)), count=2)
    assert component_agreement(_on([[0], [0]]), planar) == Agreement(2, 2, None, None, None)
    assert component_agreement(_on([[0], [0]]), planar).right  # type: ignore[union-attr]
    # The ODE trace labels no component.
    ode = MethodTarget(np.zeros(1), np.zeros(1), np.zeros((1, 7)), np.zeros(1), np.zeros(1),
                       None, 1, 1.0)  # fmt: skip
    assert component_agreement(ode, FOUR_D) is None


def test_a_component_only_its_path_returned_still_counts() -> None:
    # Component 1 holds no accepted sample: only path points, on exact component B.
    answer = _on([[0], [1, 1]], on_path=np.array([False, True, True]))
    assert component_agreement(answer, FOUR_D) == Agreement(2, 2, 0, 0, 0)
    assert answer.kept == 1 and answer.path_points == 2


def test_wrong_count_targets_names_splits_and_merges() -> None:
    answers = [_on([[0], [1]]), _on([[0], [0], [1]]), _on([[0, 1], [1]])]
    assert wrong_count_targets(answers, [FOUR_D] * 3) == [
        {"index": 1, "expected": 2, "returned": 3, "splits": 1, "merges": 0},
        {"index": 2, "expected": 2, "returned": 2, "splits": 1, "merges": 1},
    ]


def test_summary_counts_splits_times_and_checks_the_paths(iiwa14_pose_model: ServedModel) -> None:
    truth = _exact_truth([1.0, 3.0], count=2, four_d=False)
    right = _on([[0, 0, 0], [1]], on_path=np.array([False, True, True, False]))
    right.returned[2, 1] = 2.5  # a path point past q2's 120 degree limit
    right.returned_position_m = np.array([0.0, 1e-7, 2e-7, 0.0])
    right.returned_orientation_rad = np.array([0.0, 0.0, 3e-7, 0.0])
    right.sampled, right.path_max_gap_rad, right.near_singular = 10, 0.3, False
    right.stage_ms = {"connect": 1.0, "total": 2.0}
    split = _on([[0], [0], [1]], on_path=np.zeros(3, dtype=bool))
    split.sampled, split.near_singular = 10, True
    split.stage_ms = {"connect": 3.0, "total": 4.0}
    summary = summarise(iiwa14_pose_model, [right, split], [truth, truth])
    assert summary["component_count"]["right"] == 0.5  # type: ignore[index]
    assert summary["splits_per_target"] == 0.5 and summary["merges_per_target"] == 0.0
    assert summary["extra_small_per_target"] == 0.0
    assert summary["keep_rate"] == (2 + 3) / 20  # path points are not kept samples
    assert summary["limit_violations"] == 1 and summary["path_points_outside_limits"] == 1
    assert summary["path_points_mean"] == 1.0 and summary["path_max_gap_rad"] == 0.3
    assert summary["path_max_position_error_m"] == 2e-7
    assert summary["path_max_orientation_error_rad"] == 3e-7
    assert summary["near_singular_targets"] == 0.5
    assert summary["median_stage_ms"] == {"connect": 2.0, "total": 3.0}
    assert summary["p95_stage_ms"] == {"connect": 2.9, "total": 3.9}


def test_regular_targets_leave_out_the_ones_flagged_near_singular() -> None:
    """A merge on a target the answer flagged near-singular counts in the overall figures
    but not in the regular ones; unflagged targets count in both."""
    right = replace(_on([[0], [1]]), near_singular=False)
    merged_flagged = replace(_on([[0, 1]]), near_singular=True)
    split_unflagged = replace(_on([[0], [0], [1]]), near_singular=False)
    regular = regular_targets([right, merged_flagged, split_unflagged], [FOUR_D] * 3)
    assert regular == {
        "targets": 2, "count_right": 0.5, "splits_per_target": 0.5, "merges_per_target": 0.0
    }  # fmt: skip
    assert regular_targets([merged_flagged], [FOUR_D]) is None


def test_a_configuration_takes_the_component_of_its_nearest_label_node_where_nodes_exist() -> None:
    # Two 4-D components drawn sparsely: a configuration of component 0 that lies
    # between draws is nearer a draw of component 1 (0.5 against 0.6 rad), but the
    # reference's every node of component 0 passes 0.01 rad from it.
    points = np.zeros((2, 7))
    points[0, 0], points[1, 0] = -0.6, 0.5
    truth = Truth(
        points=points, count=2, point_component=np.array([0, 1]), size=np.array([0.5, 0.5]),
        size_edges=SHARE_BUCKETS, membership_joints=6,
    )  # fmt: skip
    q = np.zeros((1, 7))
    q[0, 6] = 3.0  # q7 does not decide membership
    assert exact_labels(q, truth).tolist() == [1]  # by the drawn points alone
    nodes = np.zeros((3, 6), np.float32)
    nodes[:, 0] = [-0.6, 0.01, 0.5]
    labelled = replace(truth, label_points=nodes, label_component=np.array([0, 0, 1]))
    assert exact_labels(q, labelled).tolist() == [0]
    assert exact_labels(np.zeros((0, 7)), labelled).tolist() == []
