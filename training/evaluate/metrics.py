"""The measures of an answer against exact ground truth: errors in the paper's units,
coverage and precision on the joint metric, exact components found, splits, merges and
counts, the checks of the returned paths (r = 1), and the component matching of the
iiwa pose checks; stage-time medians and 95th percentiles."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from service.models.registry import ServedModel
from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.joint_space import JointBox, JointLimits
from service.pipeline.types import SmmResult
from training.evaluate.methods import MethodTarget
from training.evaluate.references.iiwa14 import ReferenceComponent
from training.evaluate.truth import SHARE_BUCKETS, Truth

COVERAGE_RADIUS_RAD = 0.1  # an exact point is covered when an answer lies this close


def nearest_distance(query: FloatArray, data: FloatArray, periodic: BoolArray) -> FloatArray:
    """(Q,) joint-metric distance from each query configuration (Q, n) to its nearest in `data`."""
    if len(data) == 0:
        return np.full(len(query), np.inf)
    box = JointBox.covering(np.concatenate([query, data]), periodic, margin_rad=10.0)
    return box.tree(data).query(box.points(query))[0]


def coverage_p95(coverage_rad: FloatArray) -> float:
    """The 95th percentile of the exact points' distances to the nearest answer; inf where
    it falls among points with no answer at all (a target answered with nothing). numpy
    interpolates between two infinities to NaN, which no comparison finds worse."""
    with np.errstate(invalid="ignore"):
        value = float(np.percentile(coverage_rad, 95))
    return float("inf") if np.isnan(value) else value


def errors_in_units(
    position_error_m: np.ndarray, orientation_error_rad: np.ndarray, reach_m: float, pose: bool
) -> dict[str, float | None]:
    """The paper's e_p, e_o (mean, % of L and of pi) and e, with mm and degrees beside them."""
    if len(position_error_m) == 0:
        return {"e_p_pct": None, "e_o_pct": None, "e_pct": None, "mm": None, "deg": None}
    e_p = float(position_error_m.mean() / reach_m * 100)
    e_o = float(orientation_error_rad.mean() / np.pi * 100) if pose else None
    return {
        "e_p_pct": e_p,
        "e_o_pct": e_o,
        "e_pct": (e_p + e_o) / 2 if e_o is not None else e_p,
        "mm": float(position_error_m.mean() * 1e3),
        "deg": float(np.degrees(orientation_error_rad.mean())) if pose else None,
    }


COUNT_RIGHT_DEFINITION = (
    "A target's count is right when the number of returned components equals the exact "
    "count, no returned component is a merge (its configurations lie on two or more exact "
    "components) and no exact component is split (spread over two or more returned "
    "components). Each returned configuration, accepted sample or path point, belongs to "
    "the exact component of its nearest exact point. For the 4-D fibre only exact "
    "components of at least 1 % of the fibre count, as in the exact count: a returned "
    "component lying only on smaller ones is extra small, neither counted nor a split. "
    "Without exact component labels (planar 3R) the count alone is compared with the "
    "closed form."
)


@dataclass(frozen=True)
class Agreement:
    """A method's components against the exact ones on one target (`COUNT_RIGHT_DEFINITION`).

    splits, merges and extra_small are None without exact component labels (planar 3R).
    """

    returned: int  # returned components, extra-small ones left out
    expected: int  # the exact count (Truth.count)
    splits: int | None  # counted exact components spread over 2+ returned components
    merges: int | None  # returned components lying on 2+ counted exact components
    extra_small: int | None  # returned components lying only on uncounted exact ones

    @property
    def right(self) -> bool:
        """The count is right: as many components as the exact count, no merge, no split."""
        return self.returned == self.expected and not self.splits and not self.merges


def counted_components(truth: Truth) -> BoolArray:
    """(C,) the exact components Truth.count counts: every one of a 1-D SMM, those of at
    least MIN_SHARE (size_edges[1]) of a 4-D fibre."""
    assert truth.size is not None
    if truth.size_edges == SHARE_BUCKETS:
        return np.asarray(truth.size >= truth.size_edges[1])
    return np.ones(len(truth.size), dtype=bool)


def exact_labels(returned: FloatArray, truth: Truth) -> np.ndarray:
    """(K,) the exact component of each returned configuration: that of its nearest exact
    label point on the membership joints (the joint metric: Euclidean where no joint is
    periodic, the iiwa's and the Panda's;
    `Truth.labelling`: every node of the 4-D reference, the points otherwise)."""
    if not len(returned):
        return np.zeros(0, int)
    points, component = truth.labelling()
    query = returned[:, : truth.membership_joints]
    if truth.periodic is not None and truth.periodic.any():
        box = JointBox.covering(np.concatenate([points, query]), truth.periodic, margin_rad=10.0)
        nearest = box.tree(points).query(box.points(query))[1]
    else:
        nearest = cKDTree(points).query(query)[1]
    return np.asarray(component[nearest])


def component_agreement(answer: MethodTarget, truth: Truth) -> Agreement | None:
    """Splits, merges and the count of one answer (`COUNT_RIGHT_DEFINITION`); None when
    the method labels no component (the ODE trace)."""
    if answer.component_count is None or answer.labels is None:
        return None
    count = answer.component_count
    if truth.point_component is None or truth.size is None:
        return Agreement(count, truth.count, None, None, None)
    counted = counted_components(truth)
    exact = exact_labels(answer.returned, truth)
    touched = [np.unique(exact[answer.labels == j]) for j in range(count)]
    holders = np.zeros(len(counted), dtype=int)
    for members in touched:
        holders[members[counted[members]]] += 1
    extra_small = sum(int(len(m) > 0 and not counted[m].any()) for m in touched)
    return Agreement(
        returned=count - extra_small,
        expected=truth.count,
        splits=int(((holders > 1) & counted).sum()),
        merges=sum(int(counted[m].sum() > 1) for m in touched),
        extra_small=extra_small,
    )


def path_checks(
    answers: list[MethodTarget], lower: FloatArray, upper: FloatArray, periodic: BoolArray
) -> dict[str, float | int | None]:
    """The returned paths (r = 1): points per target, the largest step along any path,
    points outside the limits, the largest task errors on them."""
    with_paths = [a for a in answers if a.on_path is not None]
    points = np.concatenate(
        [np.zeros((0, len(lower)))] + [a.returned[a.on_path] for a in with_paths]
    )
    position = np.concatenate(
        [np.zeros(0)] + [a.returned_position_m[a.on_path] for a in with_paths]
    )
    orientation = np.concatenate(
        [np.zeros(0)] + [a.returned_orientation_rad[a.on_path] for a in with_paths]
    )
    gaps = [a.path_max_gap_rad for a in answers if a.path_max_gap_rad is not None]
    regular_gaps = [
        a.path_max_gap_rad
        for a in answers
        if a.path_max_gap_rad is not None and a.near_singular is False
    ]
    outside = (~(periodic | ((points >= lower) & (points <= upper)))).any(axis=1)
    return {
        "path_points_mean": float(np.mean([a.path_points for a in answers])),
        "path_max_gap_rad": max(gaps) if gaps else None,
        # Near a singular point a point Newton cannot make exact is left out (and the
        # answer flagged): the gap is bounded by the contract only on the other targets.
        "path_max_gap_rad_not_near_singular": max(regular_gaps) if regular_gaps else None,
        "path_points_outside_limits": int(outside.sum()),
        "path_max_position_error_m": float(position.max()) if len(position) else None,
        "path_max_orientation_error_rad": float(orientation.max()) if len(orientation) else None,
    }


def coverage_and_precision(
    answers: list[MethodTarget], truths: list[Truth], periodic: np.ndarray
) -> dict[str, object]:
    """Coverage (each exact point to the nearest returned configuration) and precision
    (each returned configuration to the nearest exact point), in rad over every target."""
    coverage = [
        nearest_distance(t.points, a.returned, periodic)
        for a, t in zip(answers, truths, strict=True)
    ]
    precision = [
        nearest_distance(a.returned, t.points, periodic)
        for a, t in zip(answers, truths, strict=True)
    ]
    every_coverage, every_precision = np.concatenate(coverage), np.concatenate(precision)
    return {
        "coverage_rad": {
            "mean": float(every_coverage.mean()),
            "p95": float(np.percentile(every_coverage, 95)),
            f"within_{COVERAGE_RADIUS_RAD}": float(np.mean(every_coverage <= COVERAGE_RADIUS_RAD)),
        },
        "precision_rad": (
            {
                "mean": float(every_precision.mean()),
                "p95": float(np.percentile(every_precision, 95)),
            }
            if len(every_precision) else None
        ),
    }  # fmt: skip


def summarise(
    model: ServedModel, answers: list[MethodTarget], truths: list[Truth]
) -> dict[str, object]:
    """One method over the targets: errors, keep rate, limits, time (per stage: median and
    p95), coverage and precision, components (splits, merges, count right) and paths."""
    if not answers:
        return {}
    manifest = model.manifest
    reach, pose = manifest.reach_m, bool(manifest.task.orientation_rows)
    one_dimensional = manifest.joints.count - manifest.task.dimension == 1
    limits = JointLimits.of(manifest.joints)
    cat = np.concatenate
    raw = errors_in_units(
        cat([a.raw_position_m for a in answers]),
        cat([a.raw_orientation_rad for a in answers]),
        reach,
        pose,
    )
    returned = errors_in_units(
        cat([a.returned_position_m for a in answers]),
        cat([a.returned_orientation_rad for a in answers]),
        reach,
        pose,
    )
    outside = [~limits.contains(a.returned) for a in answers]
    summary: dict[str, object] = {
        "raw": raw,
        "returned": returned,
        "keep_rate": sum(a.kept for a in answers) / sum(a.sampled for a in answers),
        "limit_violations": int(sum(o.sum() for o in outside)),
        "median_time_ms": float(np.median([a.time_ms for a in answers])),
    }
    timed = [a.stage_ms for a in answers if a.stage_ms]
    if timed:
        summary["median_stage_ms"] = median_stage_ms(timed)
        summary["p95_stage_ms"] = p95_stage_ms(timed)
    singular = [a.near_singular for a in answers if a.near_singular is not None]
    if singular:
        summary["near_singular_targets"] = float(np.mean(singular))
    if answers[0].labels is None:
        return summary
    summary.update(coverage_and_precision(answers, truths, limits.periodic))
    if truths[0].size is not None:
        summary["recall_by_size"] = recall_by_size(answers, truths)
    agreements = [
        g
        for g in (component_agreement(a, t) for a, t in zip(answers, truths, strict=True))
        if g is not None
    ]
    counts = np.array([g.returned for g in agreements])
    expected = np.array([g.expected for g in agreements])
    summary["component_count"] = {
        "right": float(np.mean([g.right for g in agreements])),
        "too_many": float(np.mean(counts > expected)),
        "too_few": float(np.mean(counts < expected)),
        "expected_mean": float(expected.mean()),
        "returned_mean": float(counts.mean()),
    }
    if agreements[0].splits is not None:
        summary["splits_per_target"] = float(np.mean([g.splits for g in agreements]))
        summary["merges_per_target"] = float(np.mean([g.merges for g in agreements]))
        summary["extra_small_per_target"] = float(np.mean([g.extra_small for g in agreements]))
        summary["regular_targets"] = regular_targets(answers, truths)
    if one_dimensional and any(a.on_path is not None for a in answers):
        summary.update(path_checks(answers, limits.lower_rad, limits.upper_rad, limits.periodic))
    return summary


def regular_targets(
    answers: list[MethodTarget], truths: list[Truth]
) -> dict[str, float | int] | None:
    """Count right, splits and merges over the targets the answer did not flag as near a
    singular value (where the issue asks for a flag, not a particular split or merge)."""
    pairs = [(a, t) for a, t in zip(answers, truths, strict=True) if a.near_singular is False]
    agreements = [g for g in (component_agreement(a, t) for a, t in pairs) if g is not None]
    if not agreements or agreements[0].splits is None:
        return None
    return {
        "targets": len(agreements),
        "count_right": float(np.mean([g.right for g in agreements])),
        "splits_per_target": float(np.mean([g.splits for g in agreements])),
        "merges_per_target": float(np.mean([g.merges for g in agreements])),
    }


def found_components(answer: MethodTarget, truth: Truth) -> np.ndarray:
    """(C,) whether each exact component holds a returned configuration.

    A returned configuration belongs to the exact component of its nearest exact point.
    """
    assert truth.point_component is not None and truth.size is not None
    found = np.zeros(len(truth.size), dtype=bool)
    found[exact_labels(answer.returned, truth)] = True
    return found


def recall_by_size(answers: list[MethodTarget], truths: list[Truth]) -> list[dict[str, object]]:
    """Fraction of exact components holding a returned configuration, by component size."""
    edges = truths[0].size_edges
    found_by_bucket = [[0, 0] for _ in edges[:-1]]
    for answer, truth in zip(answers, truths, strict=True):
        assert truth.size is not None
        found = found_components(answer, truth)
        bucket = np.digitize(truth.size, edges[1:-1])
        for b in range(len(found_by_bucket)):
            found_by_bucket[b][0] += int(found[bucket == b].sum())
            found_by_bucket[b][1] += int((bucket == b).sum())
    return [
        {
            "size": f"{low:g}-{high:g}",
            "components": total,
            "recall": hits / total if total else None,
        }
        for (hits, total), low, high in zip(found_by_bucket, edges[:-1], edges[1:], strict=True)
    ]


def missed_components(answers: list[MethodTarget], truths: list[Truth]) -> list[dict[str, object]]:
    """Targets where an exact component above the smallest size bucket holds no answer."""
    missed = []
    for index, (answer, truth) in enumerate(zip(answers, truths, strict=True)):
        assert truth.size is not None
        lost = ~found_components(answer, truth) & (truth.size >= truth.size_edges[1])
        if lost.any():
            missed.append({"index": index, "sizes": np.round(truth.size[lost], 3).tolist()})
    return missed


def wrong_count_targets(
    answers: list[MethodTarget], truths: list[Truth]
) -> list[dict[str, object]]:
    """Targets whose count is not right (`COUNT_RIGHT_DEFINITION`): returned components
    (extra-small ones left out) against the exact count, with splits and merges when the
    ground truth labels its components."""
    wrong: list[dict[str, object]] = []
    for index, (answer, truth) in enumerate(zip(answers, truths, strict=True)):
        agreement = component_agreement(answer, truth)
        if agreement is None or agreement.right:
            continue
        entry: dict[str, object] = {
            "index": index,
            "expected": agreement.expected,
            "returned": agreement.returned,
        }
        if agreement.splits is not None:
            entry.update(splits=agreement.splits, merges=agreement.merges)
        wrong.append(entry)
    return wrong


def match_summary(matches: list[ComponentMatch]) -> dict[str, float]:
    return {
        "reference_components_mean": float(np.mean([m.reference for m in matches])),
        "recall": sum(m.found for m in matches) / sum(m.reference for m in matches),
        "merged_per_target": float(np.mean([m.merged for m in matches])),
        "split_per_target": float(np.mean([m.split for m in matches])),
        "count_right": float(np.mean([m.returned == m.reference for m in matches])),
    }


@dataclass(frozen=True)
class ComponentMatch:
    """Returned components against the exact ones of a pose (S-R-S IK ground truth).

    Each returned configuration is labelled with the reference component of its nearest
    reference point (joint metric: Euclidean, no iiwa joint is periodic).
    """

    reference: int  # feasible components of the exact SMM
    returned: int
    found: int  # reference components holding at least one returned configuration
    merged: int  # returned components whose members lie on two or more reference ones
    split: int  # reference components spread over two or more returned ones
    missed_arc_rad: list[float]  # arc lengths of the reference components not found
    coverage_p95_rad: float  # over reference points: distance to the nearest returned one

    @property
    def exact(self) -> bool:
        return self.returned == self.reference == self.found and not self.merged + self.split


def match_components(result: SmmResult, reference: list[ReferenceComponent]) -> ComponentMatch:
    """Each returned component's configurations and path points against the reference."""
    points = np.concatenate([c.q_rad for c in reference])  # (P, 7)
    owner = np.concatenate([np.full(len(c.q_rad), i) for i, c in enumerate(reference)])
    tree = cKDTree(points)
    members = [
        c.configurations_rad
        if c.path is None
        else np.concatenate([c.configurations_rad, c.path.q_rad])
        for c in result.components
    ]
    labels = [owner[tree.query(q)[1]] if len(q) else np.zeros(0, int) for q in members]
    touched = [set(label.tolist()) for label in labels]
    holders = np.zeros(len(reference), dtype=int)
    for touched_by_one in touched:
        holders[list(touched_by_one)] += 1
    returned = np.concatenate([np.zeros((0, 7)), *members])
    coverage_p95 = (
        float(np.percentile(cKDTree(returned).query(points)[0], 95)) if len(returned) else np.inf
    )
    return ComponentMatch(
        reference=len(reference),
        returned=len(result.components),
        found=int((holders > 0).sum()),
        merged=sum(len(m) > 1 for m in touched),
        split=int((holders > 1).sum()),
        missed_arc_rad=[
            round(c.arc_length_rad, 3) for c, h in zip(reference, holders, strict=True) if not h
        ],
        coverage_p95_rad=coverage_p95,
    )


def median_stage_ms(timings: list[dict[str, float]]) -> dict[str, float]:
    """Median over targets of each timed span (keys of `StageTimings.as_dict()`), 0.01 ms."""
    return {span: round(float(np.median([t[span] for t in timings])), 2) for span in timings[0]}


def p95_stage_ms(timings: list[dict[str, float]]) -> dict[str, float]:
    """95th percentile over targets of each timed span (linear interpolation), 0.01 ms."""
    return {
        span: round(float(np.percentile([t[span] for t in timings], 95)), 2) for span in timings[0]
    }
