"""Quality of an exported model, measured through the service's own pipeline stages.

Held-out targets are the FK of configurations drawn uniformly within the joint limits
with a seed distinct from training. Raw errors are over *all* samples (not only the
kept ones, unlike the paper); the keep rate is the fraction accepted after the default
correction at the default tolerances.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from service.manifest import Quality
from service.pipeline.acceptance import accept
from service.pipeline.correction import correct
from service.pipeline.sampling import sample_configurations
from service.pipeline.targets import encode_target
from service.registry import ServedModel


@dataclass(frozen=True)
class HeldOutTargets:
    q_rad: np.ndarray  # (T, n) the configurations whose FK made the targets
    position_m: np.ndarray  # (T, 3)
    rotation: np.ndarray  # (T, 3, 3)


def held_out_targets(served: ServedModel, count: int, seed: int) -> HeldOutTargets:
    lower, upper, _ = served.manifest.joints.arrays()
    q = np.random.default_rng(seed).uniform(lower, upper, size=(count, len(lower)))
    fk = served.kinematics(q)
    return HeldOutTargets(q_rad=q, position_m=fk.position_m, rotation=fk.rotation)


def orientation_wxyz(rotation: np.ndarray) -> tuple[float, float, float, float]:
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return (float(w), float(x), float(y), float(z))


def measure_quality(served: ServedModel, num_targets: int, samples: int, seed: int) -> Quality:
    manifest = served.manifest
    task, defaults = manifest.task, manifest.defaults
    lower, upper, periodic = manifest.joints.arrays()
    targets = held_out_targets(served, num_targets, seed)
    position_errors, orientation_errors, kept, solved = [], [], 0, 0
    for i in range(num_targets):
        target = encode_target(
            task,
            manifest.condition,
            targets.position_m[i, task.position_axes].tolist(),
            orientation_wxyz(targets.rotation[i]) if task.orientation else None,
        )
        q_raw = sample_configurations(
            served.velocity,
            target.condition,
            samples,
            defaults.sampler.steps,
            manifest.joint_normalisation,
            periodic,
            np.random.default_rng(seed + 1 + i),
        )
        fk = served.kinematics(q_raw)
        position_errors.append(
            np.linalg.norm(fk.position_m[:, task.position_axes] - target.position_m, axis=1)
        )
        if task.orientation:
            relative = np.swapaxes(fk.rotation, 1, 2) @ targets.rotation[i]
            orientation_errors.append(Rotation.from_matrix(relative).magnitude())
        correction = correct(
            q_raw,
            target,
            task,
            served.kinematics,
            defaults.correction_steps,
            defaults.damping,
            periodic,
        )
        accepted = accept(
            correction,
            defaults.tolerance_position_m,
            defaults.tolerance_orientation_rad,
            lower,
            upper,
            periodic,
        ).accepted
        kept += int(accepted.sum())
        solved += int(accepted.any())

    position_mm = np.concatenate(position_errors) * 1e3
    orientation_deg = np.degrees(np.concatenate(orientation_errors)) if orientation_errors else None
    return Quality(
        held_out_targets=num_targets,
        samples_per_target=samples,
        raw_position_error_mm_mean=float(position_mm.mean()),
        raw_position_error_mm_median=float(np.median(position_mm)),
        raw_position_error_pct_reach_mean=float(
            position_mm.mean() / (manifest.reach_m * 1e3) * 100
        ),
        raw_orientation_error_deg_mean=None
        if orientation_deg is None
        else float(orientation_deg.mean()),
        raw_orientation_error_deg_median=(
            None if orientation_deg is None else float(np.median(orientation_deg))
        ),
        # e_o of the paper: geodesic angle / pi, in %.
        raw_orientation_error_pct_mean=(
            None if orientation_deg is None else float(orientation_deg.mean() / 180.0 * 100)
        ),
        keep_rate=kept / (num_targets * samples),
        targets_with_solution=solved / num_targets,
        measured_by="training.evaluate.quality.measure_quality (run by smm-train after export)",
    )
