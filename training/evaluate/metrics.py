"""The measures of an answer against exact ground truth: errors in the paper's units,
coverage and precision on the joint metric, exact components found, counts, and the
component matching of the iiwa pose checks; stage-time medians."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from service.models.registry import ServedModel
from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.joint_space import JointBox
from service.pipeline.types import SmmResult
from training.evaluate.methods import MethodTarget
from training.evaluate.references.iiwa14 import ReferenceComponent
from training.evaluate.served import returned_configurations
from training.evaluate.truth import Truth

COVERAGE_RADIUS_RAD = 0.1  # an exact point is covered when an answer lies this close


def nearest_distance(query: FloatArray, data: FloatArray, periodic: BoolArray) -> FloatArray:
    """(Q,) joint-metric distance from each query configuration (Q, n) to its nearest in `data`."""
    if len(data) == 0:
        return np.full(len(query), np.inf)
    box = JointBox.covering(np.concatenate([query, data]), periodic, margin_rad=10.0)
    return box.tree(data).query(box.points(query))[0]


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


def summarise(
    model: ServedModel, answers: list[MethodTarget], truths: list[Truth]
) -> dict[str, object]:
    manifest = model.manifest
    reach, pose = manifest.reach_m, manifest.task.orientation
    lower, upper, periodic = manifest.joints.arrays()
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
    outside = [
        (~(periodic | ((a.returned >= lower) & (a.returned <= upper)))).any(axis=1) for a in answers
    ]
    summary: dict[str, object] = {
        "raw": raw,
        "returned": returned,
        "keep_rate": sum(len(a.returned) for a in answers) / sum(a.sampled for a in answers),
        "limit_violations": int(sum(o.sum() for o in outside)),
        "median_time_ms": float(np.median([a.time_ms for a in answers])),
    }
    if answers[0].stage_ms is not None:
        summary["median_stage_ms"] = median_stage_ms([a.stage_ms for a in answers if a.stage_ms])
    if answers[0].labels is None:
        return summary
    coverage = [
        nearest_distance(t.points, a.returned, periodic)
        for a, t in zip(answers, truths, strict=True)
    ]
    precision = [
        nearest_distance(a.returned, t.points, periodic)
        for a, t in zip(answers, truths, strict=True)
    ]
    every_coverage, every_precision = cat(coverage), cat(precision)
    summary["coverage_rad"] = {
        "mean": float(every_coverage.mean()),
        "p95": float(np.percentile(every_coverage, 95)),
        f"within_{COVERAGE_RADIUS_RAD}": float(np.mean(every_coverage <= COVERAGE_RADIUS_RAD)),
    }
    summary["precision_rad"] = (
        {"mean": float(every_precision.mean()), "p95": float(np.percentile(every_precision, 95))}
        if len(every_precision) else None
    )  # fmt: skip
    if truths[0].size is not None:
        summary["recall_by_size"] = recall_by_size(answers, truths)
    if answers[0].labels is not None:
        counts = np.array([a.component_count for a in answers if a.component_count is not None])
        expected = np.array([t.count for t in truths])
        summary["component_count"] = {
            "right": float(np.mean(counts == expected)),
            "too_many": float(np.mean(counts > expected)),
            "too_few": float(np.mean(counts < expected)),
            "expected_mean": float(expected.mean()),
            "returned_mean": float(counts.mean()),
        }
    return summary


def found_components(answer: MethodTarget, truth: Truth) -> np.ndarray:
    """(C,) whether each exact component holds a returned configuration.

    A returned configuration belongs to the exact component of its nearest exact point.
    """
    assert truth.point_component is not None and truth.size is not None
    found = np.zeros(len(truth.size), dtype=bool)
    if len(answer.returned):
        n = truth.membership_joints  # iiwa: no periodic joint
        nearest = cKDTree(truth.points[:, :n]).query(answer.returned[:, :n])[1]
        found[truth.point_component[nearest]] = True
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
    """Targets where the method returned another number of components than the exact one."""
    return [
        {"index": index, "expected": truth.count, "returned": answer.component_count}
        for index, (answer, truth) in enumerate(zip(answers, truths, strict=True))
        if answer.component_count is not None and answer.component_count != truth.count
    ]


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
    points = np.concatenate([c.q_rad for c in reference])  # (P, 7)
    owner = np.concatenate([np.full(len(c.q_rad), i) for i, c in enumerate(reference)])
    tree = cKDTree(points)
    labels = [owner[tree.query(c.configurations_rad)[1]] for c in result.components]
    touched = [set(label.tolist()) for label in labels]
    holders = np.zeros(len(reference), dtype=int)
    for members in touched:
        holders[list(members)] += 1
    returned = returned_configurations(result, 7)
    coverage_p95 = (
        float(np.percentile(cKDTree(returned).query(points)[0], 95)) if len(returned) else np.inf
    )
    return ComponentMatch(
        reference=len(reference),
        returned=len(result.components),
        found=int((holders > 0).sum()),
        merged=sum(len(members) > 1 for members in touched),
        split=int((holders > 1).sum()),
        missed_arc_rad=[
            round(c.arc_length_rad, 3) for c, h in zip(reference, holders, strict=True) if not h
        ],
        coverage_p95_rad=coverage_p95,
    )


def median_stage_ms(timings: list[dict[str, float]]) -> dict[str, float]:
    """Median over targets of each timed span (keys of `StageTimings.as_dict()`), 0.01 ms."""
    return {
        span: round(float(np.median([t[span] for t in timings])), 2) for span in timings[0]
    }
