"""Closed-form ground truth for the planar 3R (unit links) and the issue-2 acceptance check.

SMM of a target p at distance rho from the base: for every end-effector angle phi the
wrist w = p - (cos phi, sin phi) must be within the 2R's reach (|w| <= 2), and each
elbow branch s = +-1 gives one configuration. For rho < 1 every phi is feasible and
the two branches are two disjoint loops (2 components); for 1 < rho < 3 phi covers an
arc at whose ends the branches meet (1 component); beyond 3 there is none.

    python -m training.evaluate.planar3r          # counts over 50 targets, coverage at rho 2
    python -m training.evaluate.planar3r --sweep  # the same for candidate serving defaults
"""

from __future__ import annotations

import argparse
import json
import resource
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.joint_space import joint_distance
from service.pipeline.run import run
from service.pipeline.types import Query
from training.evaluate.metrics import median_stage_ms
from training.evaluate.references.planar3r import (
    closed_form_smm,
    expected_component_count,
    planar3r_position,
)
from training.evaluate.served import returned_configurations, stage_times_ms, with_defaults
from training.evaluate.targets import planar_targets_by_distance


@dataclass(frozen=True)
class CheckReport:
    targets: int
    count_correct: int
    wrong: list[dict[str, float]]  # rho, expected, got
    max_fk_error_m: float  # worst returned configuration, by the closed-form FK
    median_fk_error_m: float
    coverage_max_rad: float  # at rho = 2: worst distance from a closed-form point to the answer
    coverage_within_0_1: float
    keep_rate: float  # accepted / sampled over the targets
    median_total_ms: float  # per target, warm, this process
    median_stage_ms: dict[str, float]
    peak_rss_mib: float  # of this process (model loaded, all queries run)


def query(
    model: ServedModel, position: np.ndarray, num_samples: int = 1000, seed: int = 0
) -> Query:
    return Query.for_model(
        model.manifest,
        position_m=position.tolist(),
        num_samples=num_samples,
        seed=seed,
        tolerance_position_m=1e-6,
    )


def check(model: ServedModel, num_targets: int = 50, seed: int = 2) -> CheckReport:
    """Component counts against the closed form, exactness by the closed-form FK, coverage."""
    periodic = np.asarray(model.manifest.joints.periodic)
    correct, wrong, fk_errors = 0, [], [np.zeros(0)]
    accepted, sampled, timings = 0, 0, []
    run(model, query(model, np.array([2.0, 0.0])))  # warm-up: first-call allocations in onnxruntime
    for i, target in enumerate(planar_targets_by_distance(num_targets, seed)):
        result = run(model, query(model, target, seed=i))
        accepted += result.counts.accepted
        sampled += result.counts.sampled
        timings.append(stage_times_ms(result))
        rho = float(np.linalg.norm(target))
        expected = expected_component_count(rho)
        if len(result.components) == expected:
            correct += 1
        else:
            wrong.append({"rho": rho, "expected": expected, "got": len(result.components)})
        q = returned_configurations(result, 3)
        fk_errors.append(np.linalg.norm(planar3r_position(q) - target, axis=1))
    target = np.array([2.0, 0.0])
    q = returned_configurations(run(model, query(model, target)), 3)
    truth = np.concatenate(closed_form_smm(target))
    nearest = np.array([joint_distance(q, p, periodic).min() for p in truth])
    return CheckReport(
        targets=num_targets,
        count_correct=correct,
        wrong=wrong,
        max_fk_error_m=float(np.concatenate(fk_errors).max(initial=0.0)),
        median_fk_error_m=float(np.median(np.concatenate(fk_errors))),
        coverage_max_rad=float(nearest.max()),
        coverage_within_0_1=float(np.mean(nearest <= 0.1)),
        keep_rate=accepted / sampled,
        median_total_ms=float(np.median([t["total"] for t in timings])),
        median_stage_ms=median_stage_ms(timings),
        peak_rss_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    )


def sweep(model: ServedModel, num_targets: int) -> list[dict[str, object]]:
    """Count accuracy, coverage, keep rate and time for candidate sampler steps."""
    rows: list[dict[str, object]] = []
    for steps in (5, 10, 20, 50, 100):
        candidate = with_defaults(
            model, sampler=model.manifest.defaults.sampler.model_copy(update={"steps": steps})
        )
        report = check(candidate, num_targets)
        rows.append(
            {
                "sampler_steps": steps,
                "count_correct": f"{report.count_correct}/{report.targets}",
                "coverage_max_rad": round(report.coverage_max_rad, 4),
                "keep_rate": round(report.keep_rate, 4),
                "median_total_ms": round(report.median_total_ms, 1),
            }
        )
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    parser.add_argument("--model-dir", default=str(REPO_MODELS_DIR / "planar3r-position"))
    parser.add_argument("--targets", type=int, default=50)
    parser.add_argument("--seed", type=int, default=2, help="seed of the random targets")
    parser.add_argument("--sweep", action="store_true", help="measure candidate sampler steps")
    args = parser.parse_args()
    model = load_model(Path(args.model_dir), threads=0)
    if args.sweep:
        sweep(model, args.targets)
    else:
        print(json.dumps(check(model, args.targets, args.seed).__dict__, indent=1))


if __name__ == "__main__":
    main()
