"""Evaluate a model against ground truth, beside the paper's baselines; write JSON + Markdown.

Targets: the FK of configurations uniform in the joint limits (fixed seed). Ground truth:
the planar closed form, the iiwa14 S-R-S IK (pose: exact components; position: dense
exact points of the 4-D SMM, no component labels). Methods, each with the same number
of samples per target:

- FM: the flow's raw samples (default sampler), all of them;
- FM + DLS: the service's pipeline with its defaults (what a client gets);
- random-restart DLS: pytorch-kinematics PseudoInverseIK from uniform restarts, judged
  by the same acceptance and clustered with the same radius;
- ODE (1-D SMMs only): the paper's null-space RK5 trace from the generating configuration.

    python -m training.evaluate.report --model iiwa14-pose --targets 200   # -> docs/reports/
    python -m training.evaluate.report --table-2   # the README's Table 2, from the reports
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytorch_kinematics as pk
from scipy.spatial import cKDTree

from service.config import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.acceptance import accept
from service.pipeline.clustering import component_labels
from service.pipeline.correction import task_error_norms
from service.pipeline.joint_space import TWO_PI
from service.pipeline.run import Query, run
from service.pipeline.sampling import sample_configurations
from service.pipeline.targets import Target, encode_target
from service.pipeline.types import Correction
from training.evaluate.ode_baseline import trace_smm
from training.evaluate.quality import orientation_wxyz
from training.evaluate.references.iiwa14 import MIN_SHARE, SHOULDER_M, pose_smm, position_smm
from training.evaluate.references.planar3r import closed_form_smm, expected_component_count
from training.evaluate.restart_dls import random_restart_dls
from training.kinematics import load_chain
from training.robots import robot_spec

REPORTS_DIR = Path(__file__).resolve().parents[2] / "docs" / "reports"
COVERAGE_RADIUS_RAD = 0.1
# Recall of exact components is reported per size bucket: small pieces are expected
# to be missed more often at a fixed number of samples. Size is the arc length of a
# 1-D component and the share of the fibre of a 4-D one.
ARC_BUCKETS_RAD = (0.0, 0.5, 2.0, np.inf)
SHARE_BUCKETS = (0.0, MIN_SHARE, 0.1, np.inf)
PAPER_TABLE_2: dict[
    str, dict[str, tuple[float | None, ...]]
] = {  # seed Table 2 (e_p %, e_o %, e %, ms; one target, kept samples, 2000 samples)
    "planar3r-position": {
        "ODE": (2.95e-9, 0.0, 2.95e-9, 166),
        "FM": (0.144, 0.0, 0.144, 125),
        "FM + DLS": (1.56e-14, 0.0, 1.56e-14, 126),
    },
    "iiwa14-pose": {
        "ODE": (2.57e-10, 2.37e-6, 1.18e-6, 8210),
        "FM": (1.07, 1.70, 1.39, 297),
        "FM + DLS": (2.88e-10, 0.0, 1.44e-10, 375),
    },
    # Seed Sec. 5: mean FK error over 1000 targets, before and after correction; no time.
    "iiwa14-position": {
        "FM": (0.0479, None, 0.0479, None),
        "FM + DLS": (0.0013, None, 0.0013, None),
    },
}


def nearest_distance(query: np.ndarray, data: np.ndarray, periodic: np.ndarray) -> np.ndarray:
    """(Q,) joint-metric distance from each query configuration to its nearest in `data`."""
    if len(data) == 0:
        return np.full(len(query), np.inf)
    both = np.concatenate([query, data])
    lowest = both.min(axis=0)
    box = np.where(periodic, TWO_PI, both.max(axis=0) - lowest + 10.0)
    shift = np.where(periodic, 0.0, lowest)

    def into_box(q: np.ndarray) -> np.ndarray:
        points = np.where(periodic, np.mod(q, TWO_PI), q - shift)
        return np.where(points >= box, points - box, points)

    return cKDTree(into_box(data), boxsize=box).query(into_box(query))[0]


@dataclass(frozen=True)
class Truth:
    points: np.ndarray  # (P, n) exact configurations within the limits
    count: int  # number of feasible components (4-D: those of at least MIN_SHARE)
    # Component of each point, each component's size and the size buckets (iiwa only).
    point_component: np.ndarray | None = None  # (P,)
    size: np.ndarray | None = None  # (C,) arc length in rad (1-D) or share of the fibre (4-D)
    size_edges: tuple[float, ...] = ARC_BUCKETS_RAD
    # Joints that decide membership: the 4-D fibre is q1..q6's fibre times any q7.
    membership_joints: int = 7  # the first this many joints


def ground_truth(model: ServedModel, q_target: np.ndarray, seed: int) -> Truth:
    fk = model.kinematics(q_target[None])
    position, rotation = fk.position_m[0], fk.rotation[0]
    if model.manifest.robot == "planar3r":
        components = closed_form_smm(position[:2], phi_step_rad=0.002)
        count = expected_component_count(float(np.linalg.norm(position[:2])))
        return Truth(np.concatenate(components), count)
    if model.manifest.task.orientation:
        exact = pose_smm(position, rotation)
        return Truth(
            np.concatenate([c.q_rad for c in exact]),
            len(exact),
            np.concatenate([np.full(len(c.q_rad), i) for i, c in enumerate(exact)]),
            np.array([c.arc_length_rad for c in exact]),
        )
    fibre = position_smm(position, seed=seed)
    if fibre.count == 0:
        # At the edge of the workspace (arm straight) the fibre is thinner than the grid
        # and no node lands on it: the generating configuration stands for it.
        return Truth(q_target[None], 1, np.zeros(1, int), np.ones(1), SHARE_BUCKETS, 6)
    return Truth(fibre.q_rad, fibre.count, fibre.component, fibre.share, SHARE_BUCKETS, 6)


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


@dataclass
class MethodTarget:
    """One method's answer to one target."""

    raw_position_m: np.ndarray
    raw_orientation_rad: np.ndarray
    returned: np.ndarray  # (K, n) accepted configurations
    returned_position_m: np.ndarray
    returned_orientation_rad: np.ndarray
    labels: np.ndarray | None  # (K,) component of each, None for the ODE trace
    sampled: int
    time_ms: float
    stage_ms: dict[str, float] | None = None


def flow_target(
    model: ServedModel, q_target: np.ndarray, num_samples: int, seed: int
) -> MethodTarget:
    manifest = model.manifest
    fk = model.kinematics(q_target[None])
    pose = manifest.task.orientation
    position = fk.position_m[0, manifest.task.position_axes].tolist()
    wxyz = orientation_wxyz(fk.rotation[0]) if pose else None
    target = encode_target(manifest.task, manifest.condition, position, wxyz)
    _, _, periodic = manifest.joints.arrays()
    q_raw = sample_configurations(
        model.velocity, target.condition, num_samples, manifest.defaults.sampler.steps,
        manifest.joint_normalisation, periodic, np.random.default_rng(seed),
    )  # fmt: skip
    raw_p, raw_o = task_error_norms(model.kinematics(q_raw), target, manifest.task)
    query = Query.for_model(
        manifest, position_m=position, orientation_wxyz=wxyz, num_samples=num_samples, seed=seed
    )
    result = run(model, query)
    returned = [c.configurations_rad for c in result.components]
    q = np.concatenate(returned) if returned else np.zeros((0, manifest.joints.count))
    labels = np.concatenate([np.full(len(r), i) for i, r in enumerate(returned)] or [np.zeros(0)])
    p, o = (
        task_error_norms(model.kinematics(q), target, manifest.task)
        if len(q)
        else (q[:, 0], q[:, 0])
    )
    stages: dict[str, float] = {str(k): v for k, v in result.timings.as_dict().items()}
    return MethodTarget(raw_p, raw_o, q, p, o, labels, num_samples, stages["total"], stages)


def reference_target(model: ServedModel, q_target: np.ndarray) -> tuple[Target, np.ndarray]:
    """The target made by q_target (task axes; rotation for a pose task) and its 3-D position."""
    task = model.manifest.task
    fk = model.kinematics(q_target[None])
    rotation = fk.rotation[0] if task.orientation else None
    target = Target(fk.position_m[0, task.position_axes], rotation, np.zeros(1, np.float32))
    return target, fk.position_m[0]


def restart_target(
    model: ServedModel, chain: pk.SerialChain, q_target: np.ndarray, num_samples: int, seed: int
) -> MethodTarget:
    manifest = model.manifest
    target, position_m = reference_target(model, q_target)
    solutions = random_restart_dls(
        chain, manifest.joints, manifest.task, position_m, target.rotation, num_samples, seed
    )
    q = solutions.q_rad
    lower, upper, periodic = manifest.joints.arrays()
    raw_p, raw_o = task_error_norms(model.kinematics(q), target, manifest.task)
    start = time.perf_counter()
    kept = accept(
        Correction(q, raw_p, raw_o), manifest.defaults.tolerance_position_m,
        manifest.defaults.tolerance_orientation_rad, lower, upper, periodic,
    ).accepted  # fmt: skip
    labels = component_labels(q[kept], periodic, manifest.defaults.cluster_radius_rad)
    elapsed = solutions.wall_time_ms + (time.perf_counter() - start) * 1e3
    return MethodTarget(
        raw_p, raw_o, q[kept], raw_p[kept], raw_o[kept], labels, num_samples, elapsed
    )


def ode_target(model: ServedModel, q_target: np.ndarray) -> MethodTarget:
    manifest = model.manifest
    trace = trace_smm(model.kinematics, manifest.task, q_target)
    target, _ = reference_target(model, q_target)
    p, o = task_error_norms(model.kinematics(trace.q_rad), target, manifest.task)
    return MethodTarget(p, o, trace.q_rad, p, o, None, len(trace.q_rad), trace.wall_time_ms)


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
        summary["median_stage_ms"] = {
            k: round(float(np.median([a.stage_ms[k] for a in answers if a.stage_ms])), 2)
            for k in answers[0].stage_ms
        }
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
        counts = np.array(
            [int(a.labels.max(initial=-1)) + 1 for a in answers if a.labels is not None]
        )
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


def distance_from_base_m(model: ServedModel, q_targets: np.ndarray) -> np.ndarray:
    """(T,) distance of each target from the arm's base point (the iiwa's shoulder)."""
    base = SHOULDER_M if model.manifest.robot == "iiwa14" else np.zeros(3)
    return np.linalg.norm(model.kinematics(q_targets).position_m - base, axis=1)


def near_boundary(model: ServedModel, q_targets: np.ndarray) -> np.ndarray:
    """(T,) targets in the outer 10 % of the reach from the base point."""
    distance = distance_from_base_m(model, q_targets)
    return distance >= 0.9 * distance.max()


def evaluate(
    model: ServedModel, num_targets: int, seed: int, num_samples: int
) -> dict[str, object]:
    manifest = model.manifest
    lower, upper, _ = manifest.joints.arrays()
    q_targets = np.random.default_rng(seed).uniform(lower, upper, (num_targets, len(lower)))
    robot = robot_spec(manifest.robot)
    chain = load_chain(REPO_MODELS_DIR / robot.urdf, robot.end_effector_link)
    one_dimensional = manifest.joints.count - manifest.task.dimension == 1
    truths = [ground_truth(model, q, seed + i) for i, q in enumerate(q_targets)]
    flow_target(model, q_targets[0], 10, seed=0)  # warm-up: onnxruntime's first-call cost
    methods: dict[str, list[MethodTarget]] = {"FM + DLS": [], "FM": [], "random-restart DLS": []}
    if one_dimensional:
        methods["ODE"] = []
    for i, q in enumerate(q_targets):
        answer = flow_target(model, q, num_samples, seed=i)
        methods["FM + DLS"].append(answer)
        methods["FM"].append(MethodTarget(
            answer.raw_position_m, answer.raw_orientation_rad, np.zeros((0, len(q))),
            answer.raw_position_m, answer.raw_orientation_rad, None, num_samples,
            answer.stage_ms["sample"] if answer.stage_ms else float("nan"),
        ))  # fmt: skip
        methods["random-restart DLS"].append(restart_target(model, chain, q, num_samples, seed=i))
        if one_dimensional:
            methods["ODE"].append(ode_target(model, q))
    boundary = near_boundary(model, q_targets)
    report: dict[str, object] = {
        "model": model.reference,
        "targets": num_targets,
        "seed": seed,
        "num_samples": num_samples,
        "defaults": manifest.defaults.model_dump(exclude={"reasons"}),
        "methods": {name: summarise(model, answers, truths) for name, answers in methods.items()},
        "component_size": "arc length (rad)" if one_dimensional else "share of the fibre",
        "near_boundary": {
            "targets": int(boundary.sum()),
            "indices": np.flatnonzero(boundary).tolist(),
            "FM + DLS": summarise(
                model,
                [a for a, b in zip(methods["FM + DLS"], boundary, strict=True) if b],
                [t for t, b in zip(truths, boundary, strict=True) if b],
            ),
        },
    }
    answers = methods["FM + DLS"]
    if truths[0].size is not None:
        report["missed_component_targets"] = missed_components(answers, truths)
    if answers[0].labels is not None:
        report["wrong_count_targets"] = [
            {
                "index": i,
                "expected": t.count,
                "returned": int(a.labels.max(initial=-1)) + 1 if a.labels is not None else 0,
            }
            for i, (a, t) in enumerate(zip(answers, truths, strict=True))
            if a.labels is not None and int(a.labels.max(initial=-1)) + 1 != t.count
        ]
    return report


def _cell(value: object) -> str:
    return "-" if value is None else f"{value:.3g}" if isinstance(value, float) else str(value)


def _table(header: list[str], rows: list[list[object]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + " | ".join(_cell(v) for v in row) + " |" for row in rows]


def _recall_lines(methods: dict[str, dict[str, Any]], size_name: str) -> list[str]:
    rows = [
        [name, bucket["size"], bucket["components"], bucket["recall"]]
        for name, summary in methods.items()
        for bucket in summary.get("recall_by_size", [])
    ]
    if not rows:
        return []
    header = ["method", f"exact component {size_name}", "exact components", "found"]
    return ["", f"Exact components found, by {size_name}:", "", *_table(header, rows)]


def _listed_targets(report: dict[str, Any]) -> list[str]:
    boundary = report["near_boundary"]
    served = boundary["FM + DLS"]
    count = served.get("component_count") or {}
    coverage = served.get("coverage_rad") or {}
    lines = [
        "",
        f"Near-boundary targets (outer 10 % of the reach): {boundary['targets']}, indices "
        f"{boundary['indices']}. There the service (FM + DLS) keeps "
        f"{_cell(served['keep_rate'])} of its samples, gets the count right on "
        f"{_cell(count.get('right'))} of the targets (too many {_cell(count.get('too_many'))}, "
        f"too few {_cell(count.get('too_few'))}) and covers the exact SMM to p95 "
        f"{_cell(coverage.get('p95'))} rad.",
    ]
    wrong = report.get("wrong_count_targets")
    if wrong is not None:
        listed = ", ".join(
            f"{w['index']} ({w['returned']} for {w['expected']})" for w in wrong[:40]
        )
        more = f", and {len(wrong) - 40} more" if len(wrong) > 40 else ""
        lines.append(
            f"Targets with the wrong component count (returned for exact): {len(wrong)}"
            + (f": {listed}{more}." if wrong else ".")
        )
    missed = report.get("missed_component_targets")
    if missed is not None:
        edges = report["methods"]["FM + DLS"]["recall_by_size"]
        smallest = edges[1]["size"].split("-")[0] if len(edges) > 1 else "0"
        near = set(boundary["indices"])
        listed = ", ".join(
            f"{m['index']}{'*' if m['index'] in near else ''} ({', '.join(map(str, m['sizes']))})"
            for m in missed[:40]
        )
        more = f", and {len(missed) - 40} more" if len(missed) > 40 else ""
        lines.append(
            f"Targets where the service missed an exact component of {report.get('component_size')}"
            f" at least {smallest} (the missed sizes; * near the boundary): {len(missed)}"
            + (f": {listed}{more}." if missed else ".")
        )
    return lines


def markdown(model_id: str, report: dict[str, Any]) -> str:
    """The report's two tables: errors and time beside the paper's Table 2, then components."""
    methods: dict[str, dict[str, Any]] = report["methods"]
    paper = PAPER_TABLE_2.get(model_id, {})
    error_rows: list[list[object]] = []
    for name, summary in methods.items():
        errors = _method_errors(name, summary)
        quoted = paper.get(name)
        error_rows.append(
            [name, errors["e_p_pct"], errors["e_o_pct"], errors["e_pct"], errors["mm"],
             errors["deg"], None if name in ("FM", "ODE") else summary["keep_rate"],
             summary["median_time_ms"], ", ".join(_cell(v) for v in quoted) if quoted else None]
        )  # fmt: skip
    component_rows: list[list[object]] = []
    for name, summary in methods.items():
        if "coverage_rad" not in summary:
            continue
        count = summary.get("component_count") or {}
        coverage, precision = summary["coverage_rad"], summary.get("precision_rad") or {}
        component_rows.append(
            [name, count.get("right"), count.get("too_many"), count.get("too_few"),
             coverage["mean"], coverage["p95"], coverage[f"within_{COVERAGE_RADIUS_RAD}"],
             precision.get("p95"), summary["limit_violations"]]
        )  # fmt: skip
    lines = [
        f"# {model_id}: evaluation against ground truth",
        "",
        f"Model `{report['model']}`; {report['targets']} held-out targets (seed {report['seed']}), "
        f"{report['num_samples']} samples (or restarts) per target. Produced by "
        f"`python -m training.evaluate.report --model {model_id} --targets {report['targets']}`.",
        "",
        *_table(
            [
                "method",
                "e_p %",
                "e_o %",
                "e %",
                "mean mm",
                "mean deg",
                "keep rate",
                "median ms",
                "paper (e_p, e_o, e, ms)",
            ],
            error_rows,
        ),
        "",
        *_table(
            [
                "method",
                "count right",
                "too many",
                "too few",
                "coverage mean rad",
                "coverage p95 rad",
                f"within {COVERAGE_RADIUS_RAD} rad",
                "precision p95 rad",
                "limit violations",
            ],
            component_rows,
        ),
        *_recall_lines(methods, report.get("component_size", "size")),
        *_listed_targets(report),
        "",
        "Errors: the FM and ODE rows are over every raw sample or trace point, the others over "
        "returned (accepted) configurations. The paper's numbers are from one target, on kept "
        "samples only.",
    ]
    return "\n".join(lines) + "\n"


def _method_errors(name: str, summary: dict[str, Any]) -> dict[str, Any]:
    # Raw rows (the flow's samples, the ODE's trace) over every point; the others over
    # what a client gets back.
    return summary["raw"] if name in ("FM", "ODE") else summary["returned"]


def table_2(reports: dict[str, dict[str, Any]]) -> str:
    """The paper's Table 2 beside ours, and the components against ground truth, per model."""
    rows: list[list[object]] = []
    component_rows: list[list[object]] = []
    for model_id, report in reports.items():
        paper = PAPER_TABLE_2.get(model_id, {})
        for name, summary in report["methods"].items():
            errors = _method_errors(name, summary)
            quoted = paper.get(name, (None,) * 4)
            rows.append([model_id, name, errors["e_p_pct"], errors["e_o_pct"], errors["e_pct"],
                         summary["median_time_ms"], *quoted])  # fmt: skip
            count = summary.get("component_count")
            if count is not None:
                coverage = summary["coverage_rad"]
                component_rows.append([model_id, name, count["expected_mean"],
                    count["returned_mean"], count["right"], count["too_many"], count["too_few"],
                    coverage["p95"], coverage[f"within_{COVERAGE_RADIUS_RAD}"]])  # fmt: skip
    header = ["model", "method", "e_p %", "e_o %", "e %", "median ms",
              "paper e_p %", "paper e_o %", "paper e %", "paper ms"]  # fmt: skip
    component_header = ["model", "method", "exact components", "returned", "count right",
                        "too many", "too few", "coverage p95 rad",
                        f"within {COVERAGE_RADIUS_RAD} rad"]  # fmt: skip
    return "\n".join([*_table(header, rows), "", *_table(component_header, component_rows)])


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    parser.add_argument("--model", help="a model id under models/, e.g. iiwa14-pose")
    parser.add_argument("--targets", type=int, default=200)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--num-samples", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=REPORTS_DIR)
    parser.add_argument(
        "--table-2", action="store_true", help="print Table 2 of every report in --out; no run"
    )
    parser.add_argument(
        "--markdown-only", action="store_true", help="rewrite the .md from the model's .json"
    )
    args = parser.parse_args()
    if args.table_2:
        reports = {p.stem: json.loads(p.read_text()) for p in sorted(args.out.glob("*.json"))}
        print(table_2(reports))
        return
    if args.model is None:
        parser.error("--model is required (or --table-2)")
    if args.markdown_only:
        saved = json.loads((args.out / f"{args.model}.json").read_text())
        (args.out / f"{args.model}.md").write_text(markdown(args.model, saved))
        return
    model = load_model(REPO_MODELS_DIR / args.model, threads=0)
    report = evaluate(model, args.targets, args.seed, args.num_samples)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{args.model}.json").write_text(json.dumps(report, indent=1) + "\n")
    (args.out / f"{args.model}.md").write_text(markdown(args.model, report))
    print(markdown(args.model, report))


if __name__ == "__main__":
    main()
