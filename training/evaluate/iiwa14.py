"""Acceptance check of the iiwa14 models by the paper's DH table, and the sweep
that chose their serving defaults.

Held-out targets are the FK of configurations drawn uniformly within the joint limits
(fixed seed). Every returned configuration is re-checked with this module's own DH
forward kinematics (numpy, float64; shares no code with the URDF or the ONNX export)
against the target and the joint limits, and every sample is accounted for.

    python -m training.evaluate.iiwa14 --task pose        # 200 targets, defaults, N = 1000
    python -m training.evaluate.iiwa14 --task position
    python -m training.evaluate.iiwa14 --task pose --sweep --targets 50
"""

from __future__ import annotations

import argparse
import json
import resource
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.run import run
from service.pipeline.types import Query
from training.evaluate.metrics import (
    match_components,
    match_summary,
    median_stage_ms,
)
from training.evaluate.references.iiwa14 import (
    LIMITS_RAD,
    ReferenceComponent,
    dh_pose,
    pose_smm,
    position_smm,
    rotation_angle_rad,
)
from training.evaluate.served import (
    orientation_wxyz,
    returned_configurations,
    stage_times_ms,
    with_defaults,
)
from training.evaluate.targets import DhTargets, dh_targets

REACH_M = 1.2  # the paper's L for the iiwa
TOLERANCE = 1e-6  # m and rad, the service's defaults


def query(model: ServedModel, pose: np.ndarray, num_samples: int, seed: int) -> Query:
    """The query for a target pose (4, 4): its orientation too when the task is the pose."""
    orientation = model.manifest.task.orientation
    return Query.for_model(
        model.manifest,
        position_m=pose[:3, 3].tolist(),
        orientation_wxyz=orientation_wxyz(pose[:3, :3]) if orientation else None,
        num_samples=num_samples,
        seed=seed,
        tolerance_position_m=TOLERANCE,
        tolerance_orientation_rad=TOLERANCE if orientation else None,
    )


@dataclass(frozen=True)
class CheckReport:
    task: str
    targets: int
    num_samples: int
    ok_fraction: float  # targets answered with at least one component
    no_solution_targets: list[int]
    returned: int  # configurations returned over all targets (samples and path points)
    returned_path_points: int  # of which points of the components' paths (pose task)
    max_position_error_m: float  # worst returned configuration, by the DH FK
    max_orientation_error_rad: float  # by the DH FK (pose task; 0 otherwise)
    median_position_error_m: float
    median_orientation_error_rad: float
    limit_violations: int  # returned configurations outside the joint limits
    accounting_errors: int  # targets whose counts do not add up or miss an accepted sample
    keep_rate: float  # accepted / sampled
    components_mean: float
    components_median: float
    components_max: int
    median_total_ms: float  # per target, warm, this process
    median_stage_ms: dict[str, float]
    peak_rss_mib: float
    # Pose task only: against the exact components (S-R-S IK); see ComponentMatch.
    reference_components_mean: float | None = None
    recall: float | None = None  # reference components found / reference components
    merged_per_target: float | None = None
    split_per_target: float | None = None
    count_right: float | None = None


def check(model: ServedModel, num_targets: int, seed: int, num_samples: int) -> CheckReport:
    """Run every held-out target through the pipeline and re-check each answer by DH FK."""
    pose_task = model.manifest.task.orientation
    targets = dh_targets(num_targets, seed)
    run(model, query(model, targets.pose[0], num_samples, seed=-1 % 2**31))  # warm-up
    no_solution, counts, timings, matches = [], [], [], []
    position_errors, orientation_errors = [np.zeros(0)], [np.zeros(0)]
    returned = path_points = violations = accounting = accepted = sampled = 0
    for i, target in enumerate(targets.pose):
        result = run(model, query(model, target, num_samples, seed=i))
        timings.append(stage_times_ms(result))
        counts.append(len(result.components))
        if pose_task:
            matches.append(match_components(result, pose_smm(target[:3, 3], target[:3, :3])))
        if not result.components:
            no_solution.append(i)
        q = returned_configurations(result, 7)
        reached = dh_pose(q)
        position_errors.append(np.linalg.norm(reached[:, :3, 3] - target[:3, 3], axis=1))
        if pose_task:
            rotations = np.broadcast_to(target[:3, :3], reached[:, :3, :3].shape)
            orientation_errors.append(rotation_angle_rad(reached[:, :3, :3], rotations))
        violations += int((np.abs(q) > LIMITS_RAD).any(axis=1).sum())
        returned += len(q)
        samples = len(returned_configurations(result, 7, include_paths=False))
        path_points += len(q) - samples
        c = result.counts
        sizes = sum(component.size for component in result.components)
        if not (
            c.sampled == num_samples
            and c.sampled == c.accepted + c.rejected_tolerance + c.rejected_joint_limits
            and sizes == c.accepted == samples
        ):
            accounting += 1
        accepted += c.accepted
        sampled += c.sampled
    return CheckReport(
        task=model.manifest.task.name,
        targets=num_targets,
        num_samples=num_samples,
        ok_fraction=1 - len(no_solution) / num_targets,
        no_solution_targets=no_solution,
        returned=returned,
        returned_path_points=path_points,
        max_position_error_m=float(np.concatenate(position_errors).max(initial=0.0)),
        max_orientation_error_rad=float(np.concatenate(orientation_errors).max(initial=0.0)),
        median_position_error_m=float(np.median(np.concatenate(position_errors))),
        median_orientation_error_rad=float(np.median(np.concatenate(orientation_errors)))
        if pose_task
        else 0.0,
        limit_violations=violations,
        accounting_errors=accounting,
        keep_rate=accepted / sampled,
        components_mean=float(np.mean(counts)),
        components_median=float(np.median(counts)),
        components_max=int(np.max(counts)),
        median_total_ms=float(np.median([t["total"] for t in timings])),
        median_stage_ms=median_stage_ms(timings),
        peak_rss_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        **(match_summary(matches) if matches else {}),
    )


def pose_sweep_row(
    model: ServedModel, targets: DhTargets, references: list[list[ReferenceComponent]], n: int
) -> dict[str, object]:
    matches = [
        match_components(run(model, query(model, pose, n, seed=i)), references[i])
        for i, pose in enumerate(targets.pose)
    ]
    defaults = model.manifest.defaults
    return {
        "num_samples": n,
        "sampler_steps": defaults.sampler.steps,
        "trace_step_rad": defaults.connectivity.trace_step_rad,
        "exact_components": round(float(np.mean([m.exact for m in matches])), 3),
        "count_right": round(float(np.mean([m.returned == m.reference for m in matches])), 3),
        "recall": round(sum(m.found for m in matches) / sum(m.reference for m in matches), 4),
        "merged_per_target": round(float(np.mean([m.merged for m in matches])), 3),
        "split_per_target": round(float(np.mean([m.split for m in matches])), 3),
        "coverage_p95_rad": round(float(np.median([m.coverage_p95_rad for m in matches])), 3),
        "longest_missed_arc_rad": max((a for m in matches for a in m.missed_arc_rad), default=0),
    }


def with_connectivity(model: ServedModel, **changes: object) -> ServedModel:
    """The model with some connect-stage parameters changed."""
    spec = model.manifest.defaults.connectivity.model_copy(update=changes)
    return with_defaults(model, connectivity=spec)


def component_counts(
    model: ServedModel, targets: DhTargets, num_samples: int, seed: int = 0
) -> np.ndarray:
    """(T,) number of components returned per target."""
    return np.array(
        [
            len(run(model, query(model, t, num_samples, seed=seed + i)).components)
            for i, t in enumerate(targets.pose)
        ]
    )


def sweep(
    model: ServedModel, num_targets: int, seed: int, correction_sweep: bool = True
) -> list[dict[str, object]]:
    """Candidate serving defaults, measured.

    Sampler steps: keep rate, answered targets and time. Connect-stage step and num_samples:
    for the pose task, against the exact components of each target (S-R-S IK): found,
    merged, split; for the position task against the exact count of components of at
    least MIN_SHARE of the fibre (grid reference), with the count's stability under
    another seed beside it.
    """
    rows: list[dict[str, object]] = []

    def emit(row: dict[str, object]) -> None:
        rows.append(row)
        print(json.dumps(row), flush=True)

    targets = dh_targets(num_targets, seed)
    pose_task = model.manifest.task.orientation
    sampler_and_correction: list[tuple[int | None, int | None]] = [
        (steps, None) for steps in (10, 20, 50)
    ]
    sampler_and_correction += [(None, dls) for dls in (3, 5, 8, 12)]
    if not correction_sweep:
        sampler_and_correction = []
    for steps, dls in sampler_and_correction:
        changes: dict[str, object] = {}
        if steps is not None:
            changes["sampler"] = model.manifest.defaults.sampler.model_copy(update={"steps": steps})
        if dls is not None:
            changes["correction_steps"] = dls
        candidate = with_defaults(model, **changes)
        report = check(candidate, num_targets, seed, 1000)
        emit(
            {
                "sampler_steps": candidate.manifest.defaults.sampler.steps,
                "correction_steps": candidate.manifest.defaults.correction_steps,
                "keep_rate": round(report.keep_rate, 4),
                "ok_fraction": report.ok_fraction,
                "median_total_ms": round(report.median_total_ms, 1),
                "median_sample_ms": report.median_stage_ms["sample"],
                "median_correct_ms": report.median_stage_ms["correct"],
            }
        )
    if pose_task:
        references = [pose_smm(p[:3, 3], p[:3, :3]) for p in targets.pose]
        for step in (0.1, 0.15, 0.2):
            emit(pose_sweep_row(with_connectivity(model, trace_step_rad=step), targets,
                                references, 1000))  # fmt: skip
        for n in (500, 2000, 4000):
            emit(pose_sweep_row(model, targets, references, n))
        return rows
    # 4-D components are sparse at N = 1000 (nearest neighbours ~0.8 rad apart): against
    # the exact components of the grid reference, with the count's seed stability beside.
    expected = np.array([position_smm(p[:3, 3], seed=i).count for i, p in enumerate(targets.pose)])
    for delta in (0.1, 0.2, 0.3):
        candidate = with_connectivity(model, delta_rad=delta)
        base = component_counts(candidate, targets, 1000, seed=0)
        reseeded = component_counts(candidate, targets, 1000, seed=10_000)
        emit(
            {
                "delta_rad": delta,
                "components_mean": round(float(base.mean()), 2),
                "exact_components_mean": round(float(expected.mean()), 2),
                "count_right": round(float(np.mean(base == expected)), 3),
                "too_many": round(float(np.mean(base > expected)), 3),
                "too_few": round(float(np.mean(base < expected)), 3),
                "same_count_other_seed": round(float(np.mean(base == reseeded)), 3),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    parser.add_argument("--task", choices=("pose", "position"), required=True)
    parser.add_argument("--model-dir", help="default: models/iiwa14-<task>")
    parser.add_argument("--targets", type=int, default=200)
    parser.add_argument("--seed", type=int, default=3, help="seed of the held-out targets")
    parser.add_argument("--num-samples", type=int, default=1000)
    parser.add_argument("--sweep", action="store_true", help="measure candidate defaults")
    parser.add_argument(
        "--connect-only", action="store_true", help="with --sweep: only the connect stage"
    )
    args = parser.parse_args()
    model = load_model(
        REPO_MODELS_DIR / f"iiwa14-{args.task}" if args.model_dir is None else Path(args.model_dir),
        threads=0,
    )
    if args.sweep:
        sweep(model, args.targets, args.seed, correction_sweep=not args.connect_only)
    else:
        print(json.dumps(asdict(check(model, args.targets, args.seed, args.num_samples)), indent=1))


if __name__ == "__main__":
    main()
