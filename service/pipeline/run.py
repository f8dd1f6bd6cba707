"""One query through the pipeline: target -> sample -> correct -> accept -> connect -> components.

Each stage is timed under its name in `STAGES`; the result accounts for every sample
(see `SampleCounts`). The pieces `encode`, `sample` and `answer_samples` are what `run`
calls in order; `batch.run_batch` calls the same pieces for many queries of one model,
so a target's answer in a batch is the one `run` gives it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Literal

import numpy as np

from service.pipeline.acceptance import accept
from service.pipeline.arrays import FloatArray
from service.pipeline.components import summarise_all
from service.pipeline.connect import connect
from service.pipeline.correction import correct
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import Fibre
from service.pipeline.limits import pull_into_limits
from service.pipeline.sampling import sample_configurations
from service.pipeline.targets import Target, encode_target
from service.pipeline.types import (
    Correction,
    Query,
    SampleCounts,
    SmmModel,
    SmmResult,
    Stage,
    StageTimings,
)


class Stopwatch:
    """Wall time per stage, measured by `with watch.stage(name):` blocks.

    `total`: "wall", the time since the watch was made (one query run from start to
    end); "stages", the sum of the stages (a target of a batch, whose stages do not run
    back to back).
    """

    def __init__(self, total: Literal["wall", "stages"] = "wall") -> None:
        self._start_s = time.perf_counter()
        self._total = total
        self._stage_ms: dict[Stage, float] = {}

    @contextmanager
    def stage(self, name: Stage) -> Iterator[None]:
        start_s = time.perf_counter()
        yield
        self._stage_ms[name] = (time.perf_counter() - start_s) * 1e3

    def timings(self) -> StageTimings:
        if self._total == "stages":
            total_ms = sum(self._stage_ms.values())
        else:
            total_ms = (time.perf_counter() - self._start_s) * 1e3
        return StageTimings(stage_ms=dict(self._stage_ms), total_ms=total_ms)


def encode(model: SmmModel, query: Query) -> Target:
    """Stage 1: the query's target and the flow's condition for it."""
    return encode_target(
        task=model.manifest.task,
        condition=model.manifest.condition,
        position_m=query.position_m,
        orientation_wxyz=query.orientation_wxyz,
    )


def sample(
    model: SmmModel, query: Query, target: Target, deadline: Deadline = NO_DEADLINE
) -> FloatArray:  # (N, n) rad
    """Stage 2: the query's num_samples flow samples, drawn from its seed."""
    manifest = model.manifest
    return sample_configurations(
        velocity=model.velocity,
        condition=target.condition,
        num_samples=query.num_samples,
        sampler=manifest.defaults.sampler,
        joint_normalisation=manifest.joint_normalisation,
        periodic=manifest.joints.arrays()[2],
        rng=np.random.default_rng(query.seed),
        deadline=deadline,
    )


def fibre_of(model: SmmModel, target: Target) -> Fibre:
    """The target's fibre, projected onto with the model's kinematics and DLS damping."""
    manifest = model.manifest
    return Fibre(target, manifest.task, model.kinematics, manifest.defaults.damping)


def correct_samples(
    model: SmmModel,
    target: Target,
    q_sampled_rad: FloatArray,  # (N, n)
    tolerance_position_m: float,
    tolerance_orientation_rad: float,
    deadline: Deadline = NO_DEADLINE,
) -> Correction:
    """Stage 3: the model's DLS steps on every sample, then for r > 1 the samples within
    tolerance outside the limits pulled into them (limits.py)."""
    manifest, defaults = model.manifest, model.manifest.defaults
    correction = correct(
        q_rad=q_sampled_rad,
        target=target,
        task=manifest.task,
        kinematics=model.kinematics,
        steps=defaults.correction_steps,
        damping=defaults.damping,
        periodic=manifest.joints.arrays()[2],
        deadline=deadline,
    )
    return into_limits(
        model, target, correction, tolerance_position_m, tolerance_orientation_rad, deadline
    )


def into_limits(
    model: SmmModel,
    target: Target,
    correction: Correction,
    tolerance_position_m: float,
    tolerance_orientation_rad: float,
    deadline: Deadline = NO_DEADLINE,
) -> Correction:
    """For r > 1, the corrected samples within tolerance but outside the limits pulled
    into them (limits.py); for r = 1 the correction as it is."""
    manifest = model.manifest
    lower_rad, upper_rad, periodic = manifest.joints.arrays()
    if manifest.redundancy == 1:
        return correction
    return pull_into_limits(
        correction=correction,
        fibre=fibre_of(model, target),
        lower_rad=lower_rad,
        upper_rad=upper_rad,
        periodic=periodic,
        tolerance_position_m=tolerance_position_m,
        tolerance_orientation_rad=tolerance_orientation_rad,
        deadline=deadline,
    )


def answer_samples(
    model: SmmModel,
    query: Query,
    target: Target,
    q_sampled_rad: FloatArray,  # (N, n) from `sample`
    watch: Stopwatch,
    deadline: Deadline = NO_DEADLINE,
) -> SmmResult:
    """Stages 3-6 on the query's samples, each timed on `watch`: correct
    (`correct_samples`), accept, connect, summarise."""
    manifest, defaults = model.manifest, model.manifest.defaults
    lower_rad, upper_rad, periodic = manifest.joints.arrays()
    with watch.stage("correct"):
        correction = correct_samples(
            model,
            target,
            q_sampled_rad,
            tolerance_position_m=query.tolerance_position_m,
            tolerance_orientation_rad=query.tolerance_orientation_rad,
            deadline=deadline,
        )
    with watch.stage("accept"):
        acceptance = accept(
            correction=correction,
            tolerance_position_m=query.tolerance_position_m,
            tolerance_orientation_rad=query.tolerance_orientation_rad,
            lower_rad=lower_rad,
            upper_rad=upper_rad,
            periodic=periodic,
        )
    with watch.stage("connect"):
        connection = connect(
            fibre=fibre_of(model, target),
            correction=correction,
            acceptance=acceptance,
            lower_rad=lower_rad,
            upper_rad=upper_rad,
            periodic=periodic,
            spec=defaults.connectivity,
            tolerance_position_m=query.tolerance_position_m,
            tolerance_orientation_rad=query.tolerance_orientation_rad,
            deadline=deadline,
            coaxial_sets=model.coaxial_sets,
        )
    with watch.stage("summarise"):
        summaries = summarise_all(
            components=connection.components,
            periodic=periodic,
            reference_rad=query.reference_rad,
            max_configurations=query.max_configurations_per_component,
            include_paths=query.include_paths,
            deadline=deadline,
        )

    return SmmResult(
        counts=SampleCounts.of(acceptance),
        components=summaries,
        structure=connection.structure,
        timings=watch.timings(),
    )


def run(model: SmmModel, query: Query, deadline: Deadline = NO_DEADLINE) -> SmmResult:
    """Stages 1-5 for one query; past `deadline`, DeadlineExceededError names the stage."""
    watch = Stopwatch()
    with watch.stage("encode"):
        target = encode(model, query)
    with watch.stage("sample"):
        q_sampled_rad = sample(model, query, target, deadline)
    return answer_samples(model, query, target, q_sampled_rad, watch, deadline)
