"""Quality of an exported model, measured through the service's own pipeline stages.

Held-out targets are the FK of configurations drawn uniformly within the joint limits
with a seed distinct from training. Raw errors are over *all* samples (not only the
kept ones, unlike the paper), at the serving default sampler and at the paper's 100
uniform Euler steps; the keep rate is the fraction accepted after the default correction at
the default tolerances.

    smm-train quality --model-dir models/iiwa14-pose --write

re-measures an exported model's quality with its current defaults (after a sweep changed
them) into its manifest; the paper sampler's row is kept from the manifest (the same
float32 network, targets, seed and samples give the same row) instead of measured again.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from service.manifest import MANIFEST_FILE, Manifest, Quality, RawError, SamplerSpec
from service.models.registry import ServedModel, load_model
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.correction import task_error_norms
from service.pipeline.joint_space import JointLimits
from service.pipeline.run import correct_samples, space_of
from service.pipeline.sampling import sample_configurations
from service.pipeline.targets import encode_target, fields_reached
from service.pipeline.types import Tolerance
from training.evaluate.targets import held_out_targets

PAPER_SAMPLER = SamplerSpec(method="euler", steps=100, time_power=1.0)
# The paper reports its FM rows over samples with e = (e_p + e_o) / 2 < 0.02 only.
PAPER_KEPT_BELOW = 0.02


def summarise_raw(
    sampler: SamplerSpec,
    position_m: np.ndarray,  # (T, N) error of N samples for each of T targets
    orientation_rad: np.ndarray,  # (T, N)
    reach_m: float,
    pose: bool,
) -> RawError:
    """Means and medians over all samples, beside the paper's kept-only and best-of-N."""
    position_mm = position_m * 1e3
    orientation_deg = np.degrees(orientation_rad)
    e_p = position_m / reach_m  # (T, N)
    e_o = orientation_rad / np.pi
    e = (e_p + e_o) / 2 if pose else e_p
    kept = e < PAPER_KEPT_BELOW  # (T, N)
    return RawError(
        sampler_steps=sampler.steps,
        sampler_flow=sampler.flow,
        sampler_precision=sampler.precision,
        sampler_time_power=sampler.time_power,
        position_error_mm_mean=float(position_mm.mean()),
        position_error_mm_median=float(np.median(position_mm)),
        position_error_pct_reach_mean=float(position_m.mean() / reach_m * 100),
        orientation_error_deg_mean=float(orientation_deg.mean()) if pose else None,
        orientation_error_deg_median=float(np.median(orientation_deg)) if pose else None,
        orientation_error_pct_mean=float(orientation_deg.mean() / 180 * 100) if pose else None,
        kept_only_fraction=float(kept.mean()),
        kept_only_position_error_pct_reach_mean=float(e_p[kept].mean() * 100)
        if kept.any()
        else None,
        kept_only_orientation_error_pct_mean=float(e_o[kept].mean() * 100)
        if pose and kept.any()
        else None,
        best_of_n_position_error_pct_reach_mean=float(e_p.min(axis=1).mean() * 100),
    )


def same_sampler(row: RawError, sampler: SamplerSpec) -> bool:
    return (row.sampler_flow, row.sampler_steps, row.sampler_time_power,
            row.sampler_precision) == (
        sampler.flow, sampler.steps, sampler.time_power, sampler.precision,
    )  # fmt: skip


def measure_quality(
    served: ServedModel,
    num_targets: int,
    samples: int,
    seed: int,
    paper_row: RawError | None = None,
) -> Quality:
    """`paper_row`: the paper sampler's row measured earlier on the same network, targets
    (num_targets, seed) and samples, kept instead of measured again."""
    manifest = served.manifest
    task, defaults = manifest.task, manifest.defaults
    limits, tolerance = JointLimits.of(manifest.joints), Tolerance.of(defaults)
    targets = held_out_targets(served, num_targets, seed)
    # The serving default first (it is also corrected), then the paper's sampler.
    samplers = [defaults.sampler]
    if defaults.sampler != PAPER_SAMPLER and paper_row is None:
        samplers.append(PAPER_SAMPLER)
    if paper_row is not None and not same_sampler(paper_row, PAPER_SAMPLER):
        raise ValueError(f"paper_row was measured with another sampler: {paper_row}")
    errors: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in samplers]
    kept, solved = 0, 0
    for i in range(num_targets):
        fields = fields_reached(task, targets.position_m[i], targets.rotation[i])
        target = encode_target(
            task, manifest.condition, fields.position_m, fields.orientation_wxyz, fields.axis
        )
        for sampler, sampler_errors in zip(samplers, errors, strict=True):
            q_raw = sample_configurations(
                served.network(sampler),
                target.condition,
                samples,
                sampler,
                manifest.joint_normalisation,
                limits,
                np.random.default_rng(seed + 1 + i),
            )
            sampler_errors.append(task_error_norms(served.kinematics(q_raw), target, task))
            if sampler != defaults.sampler:
                continue
            space = space_of(served, target, tolerance, CollisionCheck.none())
            accepted = space.accept(correct_samples(served, space, q_raw)).accepted
            kept += int(accepted.sum())
            solved += int(accepted.any())

    raw = [
        summarise_raw(
            sampler,
            np.stack([p for p, _ in sampler_errors]),
            np.stack([o for _, o in sampler_errors]),
            manifest.reach_m,
            bool(task.orientation_rows),
        )
        for sampler, sampler_errors in zip(samplers, errors, strict=True)
    ]
    if paper_row is not None and defaults.sampler != PAPER_SAMPLER:
        raw.append(paper_row)
    return Quality(
        held_out_targets=num_targets,
        samples_per_target=samples,
        raw=raw,
        keep_rate=kept / (num_targets * samples),
        targets_with_solution=solved / num_targets,
        measured_by="training.evaluate.quality.measure_quality (run by smm-train after export)",
    )


def remeasure(model_dir: Path, threads: int = 1) -> Quality:
    """`measure_quality` of an exported model with its current defaults, on the targets,
    seed and samples its training config records, its paper-sampler row kept."""
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    config = manifest.training.config
    num_targets, samples = int(config["eval_targets"]), int(config["eval_samples_per_target"])  # type: ignore[call-overload]
    known = manifest.quality
    paper_row = None
    if known is not None and (known.held_out_targets, known.samples_per_target) == (
        num_targets, samples,
    ):  # fmt: skip
        paper_row = next((r for r in known.raw if same_sampler(r, PAPER_SAMPLER)), None)
    served = load_model(model_dir, threads=threads)
    return measure_quality(served, num_targets, samples, int(config["eval_seed"]), paper_row)  # type: ignore[call-overload]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train quality`."""
    parser.add_argument("--model-dir", required=True, type=Path)
    parser.add_argument("--write", action="store_true", help="write it into the manifest")


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train quality`: measure the quality again, print it, and with --write keep it."""
    del parser
    quality = remeasure(args.model_dir)
    print(json.dumps(quality.model_dump(), indent=1))
    if args.write:
        path = args.model_dir / MANIFEST_FILE
        manifest = Manifest.model_validate_json(path.read_bytes())
        manifest = manifest.model_copy(update={"quality": quality})
        path.write_text(manifest.model_dump_json(indent=2, exclude_unset=True) + "\n")
