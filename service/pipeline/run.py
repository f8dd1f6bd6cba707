"""One query through the pipeline: target -> sample -> correct -> accept -> connect -> components.

Stages 3 to 5 move in the query's `FibreSpace` (space.py): the target's fibre inside the
joint limits, which says what configuration and what motion is valid.

Each stage is timed under its name in `STAGES`; the result accounts for every sample
(see `SampleCounts`). `run` calls `encode`, then `answer`: `sample` and `answer_samples`
(correct, accept, `answer_accepted`: connect, summarise), or for an r = 1 model that
samples in rounds, stages 2-4 round by round (rounds.py) and then `answer_accepted`.
`batch.run_batch` calls the same pieces for many queries of one model, so a target's
answer in a batch is the one `run` gives it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Literal, cast

import numpy as np

from service.pipeline.arrays import FloatArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.components import summarise_all
from service.pipeline.connect import Extension, connect
from service.pipeline.correction import correct, correct_further
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import Fibre
from service.pipeline.limits import pull_into_limits
from service.pipeline.rounds import draw_in_rounds
from service.pipeline.rows import ANSWERING
from service.pipeline.sampling import sample_configurations
from service.pipeline.space import FibreSpace
from service.pipeline.targets import Target, encode_target
from service.pipeline.types import (
    Acceptance,
    Correction,
    Query,
    SampleCounts,
    SmmModel,
    SmmResult,
    Stage,
    StageTimings,
    Tolerance,
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
        # A stage run more than once (each round of rounds.py) counts each time.
        self._stage_ms[name] = self._stage_ms.get(name, 0.0) + (time.perf_counter() - start_s) * 1e3

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
        axis=query.axis,
    )


def sample(
    model: SmmModel,
    query: Query,
    target: Target,
    deadline: Deadline = NO_DEADLINE,
    count: int | None = None,
    rng: np.random.Generator | None = None,
) -> FloatArray:  # (N, n) rad
    """Stage 2: the query's num_samples flow samples, drawn from its seed; or `count` of
    them, the next from `rng` (a round of rounds.py)."""
    manifest = model.manifest
    return sample_configurations(
        velocity=model.velocity,
        condition=target.condition,
        num_samples=query.num_samples if count is None else count,
        sampler=manifest.defaults.sampler,
        joint_normalisation=manifest.joint_normalisation,
        limits=model.limits,
        rng=np.random.default_rng(query.seed) if rng is None else rng,
        deadline=deadline,
        threads=model.row_threads,
    )


def fibre_of(model: SmmModel, target: Target) -> Fibre:
    """The target's fibre, projected onto with the model's kinematics and DLS damping, the
    compiled steps' rows over the model's threads."""
    manifest = model.manifest
    return Fibre(
        target, manifest.task, model.kinematics, manifest.defaults.damping, model.row_threads
    )


def collision_of(model: SmmModel, query: Query) -> CollisionCheck:
    """What the query checks: its obstacles, and self-collision when it asks for it, on
    the model's bodies (none when its URDF has no collision geometry), by its margin."""
    return CollisionCheck(
        robot=model.robot_spheres,
        scene=query.scene,
        check_self=query.check_self,
        margin_m=query.margin_m,
        threads=model.row_threads,
    )


def space_of(
    model: SmmModel, target: Target, tolerance: Tolerance, collision: CollisionCheck
) -> FibreSpace:
    """The space stages 3 to 5 move in: the target's fibre inside the model's joint
    limits, with the model's coaxial sets, the query's tolerance and collision check."""
    return FibreSpace(
        fibre=fibre_of(model, target),
        limits=model.limits,
        coaxial_sets=tuple(model.coaxial_sets),
        tolerance=tolerance,
        collision=collision,
    )


def correct_samples(
    model: SmmModel,
    space: FibreSpace,
    q_sampled_rad: FloatArray,  # (N, n)
    deadline: Deadline = NO_DEADLINE,
) -> Correction:
    """Stage 3: the model's DLS steps on every sample, taken further where none came
    within tolerance (`correct_further`), then for r > 1 the samples within tolerance
    outside the limits pulled into them (`into_limits`)."""
    manifest, defaults = model.manifest, model.manifest.defaults
    correction = correct(
        q_rad=q_sampled_rad,
        target=space.fibre.target,
        task=manifest.task,
        kinematics=model.kinematics,
        steps=defaults.correction_steps,
        damping=defaults.damping,
        limits=space.limits,
        deadline=deadline,
        threads=model.row_threads,
    )
    correction = correct_further(
        correction, space.tolerance, space.fibre.target, manifest.task, model.kinematics,
        defaults.damping, space.limits, deadline, model.row_threads,
    )  # fmt: skip
    return into_limits(model, space, correction, deadline)


def into_limits(
    model: SmmModel, space: FibreSpace, correction: Correction, deadline: Deadline = NO_DEADLINE
) -> Correction:
    """For r > 1, the corrected samples within tolerance but outside the limits pulled
    into them (limits.py); for r = 1 the correction as it is."""
    if model.manifest.redundancy == 1:
        return correction
    return pull_into_limits(correction, space, deadline=deadline)


def answer_samples(
    model: SmmModel,
    query: Query,
    target: Target,
    q_sampled_rad: FloatArray,  # (N, n) from `sample`
    watch: Stopwatch,
    deadline: Deadline = NO_DEADLINE,
) -> SmmResult:
    """Stages 3-6 on the query's samples, each timed on `watch`, in the query's space
    (`space_of`): correct (`correct_samples`), accept, connect, summarise."""
    space = space_of(model, target, query.tolerance, collision_of(model, query))
    return answer_in(model, query, space, q_sampled_rad, watch, deadline)


def answer_in(
    model: SmmModel,
    query: Query,
    space: FibreSpace,
    q_sampled_rad: FloatArray,  # (N, n) from `sample`
    watch: Stopwatch,
    deadline: Deadline = NO_DEADLINE,
) -> SmmResult:
    """Stages 3-6 of `answer_samples` in a given space (the evaluation passes one whose
    collision check records what it is asked)."""
    with watch.stage("correct"):
        correction = correct_samples(model, space, q_sampled_rad, deadline)
    with watch.stage("accept"):
        acceptance = space.accept(correction)
    return answer_accepted(model, query, space, correction, acceptance, watch, deadline)


def answer_accepted(
    model: SmmModel,
    query: Query,
    space: FibreSpace,
    correction: Correction,
    acceptance: Acceptance,
    watch: Stopwatch,
    deadline: Deadline = NO_DEADLINE,
    traced: Extension | None = None,
) -> SmmResult:
    """Stages 5-6 on corrected and accepted samples: connect (from `traced`, when the
    rounds traced the curves), summarise."""
    with watch.stage("connect"):
        spec = model.manifest.defaults.connectivity
        connection = connect(space, correction, acceptance, spec, deadline, traced)
    with watch.stage("summarise"):
        summaries = summarise_all(
            components=connection.components,
            limits=space.limits,
            collision=space.collision,
            reference_rad=query.reference_rad,
            max_configurations=query.max_configurations_per_component,
            include_paths=query.include_paths,
            deadline=deadline,
            include_roadmap=query.include_roadmap,
        )

    return SmmResult(
        counts=SampleCounts.of(acceptance),
        components=summaries,
        structure=connection.structure,
        timings=watch.timings(),
    )


def in_rounds(model: SmmModel, query: Query) -> bool:
    """Whether the query is drawn in rounds (rounds.py): an r = 1 model with a round size
    below the query's num_samples."""
    size = model.manifest.defaults.sampler.round_samples
    return model.manifest.redundancy == 1 and size is not None and size < query.num_samples


def answer(
    model: SmmModel,
    query: Query,
    target: Target,
    watch: Stopwatch,
    deadline: Deadline = NO_DEADLINE,
    space: FibreSpace | None = None,
) -> SmmResult:
    """Stages 2-6 for one encoded query, in `space` (default `space_of` the query): drawn
    in rounds where the model samples so (`in_rounds`), else all at once."""
    with ANSWERING.entered():
        return _answer(model, query, target, watch, deadline, space)


def _answer(
    model: SmmModel,
    query: Query,
    target: Target,
    watch: Stopwatch,
    deadline: Deadline,
    space: FibreSpace | None,
) -> SmmResult:
    if space is None:
        space = space_of(model, target, query.tolerance, collision_of(model, query))
    if not in_rounds(model, query):
        with watch.stage("sample"):
            q_sampled_rad = sample(model, query, target, deadline)
        return answer_in(model, query, space, q_sampled_rad, watch, deadline)
    manifest = model.manifest
    rng = np.random.default_rng(query.seed)  # one stream for every round
    drawn = draw_in_rounds(
        space,
        num_samples=query.num_samples,
        round_samples=cast(int, manifest.defaults.sampler.round_samples),
        draw=lambda count: sample(model, query, target, deadline, count, rng),
        correct=lambda q: correct_samples(model, space, q, deadline),
        spec=manifest.defaults.connectivity,
        stage=watch.stage,
        deadline=deadline,
    )
    return answer_accepted(
        model, query, space, drawn.correction, drawn.acceptance, watch, deadline, drawn.traced
    )


def run(model: SmmModel, query: Query, deadline: Deadline = NO_DEADLINE) -> SmmResult:
    """Stages 1-6 for one query; past `deadline`, DeadlineExceededError names the stage."""
    watch = Stopwatch()
    with watch.stage("encode"):
        target = encode(model, query)
    return answer(model, query, target, watch, deadline)
