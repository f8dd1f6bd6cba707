"""One method's answer to one target, as the report measures it: the service (flow +
DLS), the flow's raw samples, random-restart DLS and the ODE trace."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pytorch_kinematics as pk

from service.models.registry import ServedModel
from service.pipeline.acceptance import accept
from service.pipeline.clustering import component_labels
from service.pipeline.correction import task_error_norms
from service.pipeline.run import run
from service.pipeline.sampling import sample_configurations
from service.pipeline.targets import Target, encode_target
from service.pipeline.types import Correction, Query
from training.evaluate.baselines.ode import trace_smm
from training.evaluate.baselines.restart_dls import random_restart_dls
from training.evaluate.served import orientation_wxyz, stage_times_ms


@dataclass
class MethodTarget:
    """One method's answer to one target."""

    raw_position_m: np.ndarray  # (S,) task-space error of every raw sample
    raw_orientation_rad: np.ndarray  # (S,) zeros when the task has no orientation
    returned: np.ndarray  # (K, n) accepted configurations
    returned_position_m: np.ndarray  # (K,)
    returned_orientation_rad: np.ndarray  # (K,)
    labels: np.ndarray | None  # (K,) component of each, None for the ODE trace
    sampled: int  # samples drawn (the denominator of the keep rate)
    time_ms: float
    stage_ms: dict[str, float] | None = None  # per timed span (the pipeline only)

    @property
    def component_count(self) -> int | None:
        """How many components the method returned; None when it labels none (the ODE)."""
        return None if self.labels is None else int(self.labels.max(initial=-1)) + 1


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
    stages = stage_times_ms(result)
    return MethodTarget(raw_p, raw_o, q, p, o, labels, num_samples, stages["total"], stages)


def raw_samples_target(answer: MethodTarget) -> MethodTarget:
    """The flow alone (FM): the service's raw samples, none returned, timed by its sampler."""
    return MethodTarget(
        raw_position_m=answer.raw_position_m,
        raw_orientation_rad=answer.raw_orientation_rad,
        returned=np.zeros((0, answer.returned.shape[1])),
        returned_position_m=answer.raw_position_m,
        returned_orientation_rad=answer.raw_orientation_rad,
        labels=None,
        sampled=answer.sampled,
        time_ms=answer.stage_ms["sample"] if answer.stage_ms else float("nan"),
    )


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


