"""One query through the pipeline: target -> sample -> correct -> accept -> cluster.

Each stage is timed; the result accounts for every sample (see `Counts`).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from service.errors import RequestFieldError
from service.pipeline.acceptance import accept
from service.pipeline.clustering import component_labels
from service.pipeline.components import ComponentSummary, summarise_all
from service.pipeline.correction import correct
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.sampling import sample_configurations
from service.pipeline.targets import encode_target
from service.pipeline.types import Component, Counts, FloatArray, StageTimings
from service.registry import ServedModel


@dataclass(frozen=True)
class Query:
    """A validated request, with the model's defaults already filled in."""

    position_m: list[float]
    orientation_wxyz: tuple[float, float, float, float] | None
    num_samples: int
    seed: int
    tolerance_position_m: float
    tolerance_orientation_rad: float
    reference_rad: list[float] | None
    max_configurations_per_component: int | None


@dataclass(frozen=True)
class SmmResult:
    counts: Counts
    components: list[ComponentSummary]  # ordered for the response
    timings: StageTimings


class _Stopwatch:
    def __init__(self) -> None:
        self.ms: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.ms[name] = (time.perf_counter() - start) * 1e3


def reference_array(query: Query, num_joints: int) -> FloatArray | None:
    """The reference configuration (n,), or None; RequestFieldError on a wrong length."""
    if query.reference_rad is None:
        return None
    if len(query.reference_rad) != num_joints:
        raise RequestFieldError(
            ("body", "reference_configuration"),
            f"reference_configuration must have {num_joints} values (one per joint), "
            f"got {len(query.reference_rad)}",
        )
    return np.asarray(query.reference_rad, dtype=np.float64)


def run(model: ServedModel, query: Query, deadline: Deadline = NO_DEADLINE) -> SmmResult:
    """Stages 1-5 for one query; past `deadline`, DeadlineExceededError names the stage."""
    manifest = model.manifest
    defaults = manifest.defaults
    lower_rad, upper_rad, periodic = manifest.joints.arrays()
    reference_rad = reference_array(query, manifest.joints.count)
    watch = _Stopwatch()
    start = time.perf_counter()

    with watch.stage("encode"):
        target = encode_target(
            manifest.task, manifest.condition, query.position_m, query.orientation_wxyz
        )
    with watch.stage("sample"):
        q_sampled = sample_configurations(
            model.velocity,
            target.condition,
            query.num_samples,
            defaults.sampler.steps,
            manifest.joint_normalisation,
            periodic,
            np.random.default_rng(query.seed),
            deadline,
        )
    with watch.stage("correct"):
        correction = correct(
            q_sampled,
            target,
            manifest.task,
            model.kinematics,
            defaults.correction_steps,
            defaults.damping,
            periodic,
            deadline,
        )
    with watch.stage("accept"):
        acceptance = accept(
            correction,
            query.tolerance_position_m,
            query.tolerance_orientation_rad,
            lower_rad,
            upper_rad,
            periodic,
        )
    with watch.stage("cluster"):
        deadline.check("cluster")
        kept = np.flatnonzero(acceptance.accepted)  # (K,) sample indices
        labels = component_labels(correction.q_rad[kept], periodic, defaults.cluster_radius_rad)
        components = [
            Component(
                q_rad=correction.q_rad[members],
                position_error_m=correction.position_error_m[members],
                orientation_error_rad=correction.orientation_error_rad[members],
            )
            for members in (kept[labels == label] for label in range(labels.max(initial=-1) + 1))
        ]
        summaries = summarise_all(
            components, periodic, reference_rad, query.max_configurations_per_component, deadline
        )

    timings = StageTimings(
        encode_ms=watch.ms["encode"],
        sample_ms=watch.ms["sample"],
        correct_ms=watch.ms["correct"],
        accept_ms=watch.ms["accept"],
        cluster_ms=watch.ms["cluster"],
        total_ms=(time.perf_counter() - start) * 1e3,
    )
    return SmmResult(counts=Counts.of(acceptance), components=summaries, timings=timings)
