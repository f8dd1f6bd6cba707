"""What the sweep measures per candidate: each target's answer against the dense reference
of the same pipeline (keep rate, count right, merges, recall, coverage, time), and the
flow's raw error for the time grid (docs/sweep.md, Measures)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from service.manifest import (
    ConnectivitySpec,
    SamplerSpec,
)
from service.models.registry import ServedModel
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.correction import task_error_norms
from service.pipeline.joint_space import JointBox, JointLimits
from service.pipeline.run import run
from service.pipeline.sampling import sample_configurations
from service.pipeline.targets import TargetFields, encode_target, fields_reached
from service.pipeline.types import Query, SmmResult
from training.evaluate.metrics import coverage_p95, median_stage_ms
from training.evaluate.quality import summarise_raw
from training.evaluate.served import stage_times_ms, with_defaults
from training.evaluate.targets import held_out_targets
from training.sweep.plan import JOINT_DLS_AXES, Axis, Setting, connectivity_step_field

# For r > 1, reference components holding less than this share of the reference's
# accepted samples are not counted (as the 4-D exact components in the evaluation).
MIN_COMPONENT_SHARE = 0.01
# The reference's samples are drawn with the target's seed plus this, apart from the
# candidates' own.
REFERENCE_SEED_OFFSET = 1_000_003


@dataclass(frozen=True)
class ReferenceAnswer:
    """One target's dense answer: every configuration it returned and its component."""

    q_rad: FloatArray  # (P, n) accepted samples and path points, all components
    component: IntArray  # (P,) index of the component holding each
    counted: BoolArray  # (C,) the components count right and recall count
    accepted: int
    total_ms: float

    @property
    def counted_components(self) -> int:
        return int(self.counted.sum())


@dataclass(frozen=True)
class TargetAgreement:
    """One candidate answer against its target's reference."""

    sampled: int
    accepted: int
    count_right: bool
    merges: int  # returned components holding configurations of two counted reference ones
    found: int  # counted reference components holding a returned configuration
    counted: int  # counted reference components
    coverage_rad: FloatArray  # (P,) each reference configuration to the nearest returned
    stage_ms: dict[str, float]


@dataclass(frozen=True)
class Measures:
    """A candidate over the targets (docs/sweep.md defines each measure)."""

    targets: int
    answered: int
    keep_rate: float
    count_right: float
    merges_per_target: float
    recall: float | None  # None when no reference has a counted component
    coverage_p95_rad: float | None  # None without reference configurations
    median_total_ms: float
    median_stage_ms: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class Candidate:
    """A row of the sweep table: the axis swept, the setting measured, its measures."""

    axis: Axis
    setting: Setting
    measures: Measures

    @property
    def value(self) -> float:
        return self.setting.value(self.axis)

    @property
    def cost(self) -> float:
        """What `pick` orders by: on the joint reflowed-sampler x DLS axis the measured
        median sample + correct ms (docs/sweep.md), else the setting's count or step."""
        if self.axis in JOINT_DLS_AXES:
            stage_ms = self.measures.median_stage_ms
            return stage_ms["sample"] + stage_ms["correct"]
        return self.setting.cost(self.axis)

    @property
    def label(self) -> str:
        """The candidate's value as the reasons quote it (with its DLS steps on a joint axis)."""
        if self.axis in JOINT_DLS_AXES:
            return f"{self.value} at {self.setting.correction_steps} DLS"
        return f"{self.value}"

    def as_json(self) -> dict[str, object]:
        return {"axis": self.axis, **asdict(self.setting), **_finite(asdict(self.measures))}


@dataclass(frozen=True)
class TimePowerRow:
    """The sampler's raw error with one power of its time grid, over the sweep's targets."""

    time_power: float
    raw_error_pct_reach: float  # mean e = (e_p + e_o) / 2 (pose) or e_p (position), in %
    raw_position_error_mm: float  # mean |p - p*|


def _finite(values: dict[str, object]) -> dict[str, object]:
    """inf (nothing returned to measure from) as None, so that the table is strict JSON."""
    return {
        k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in values.items()
    }


# -- the measures ------------------------------------------------------------------------------


def nearest_reference(
    query_rad: FloatArray,  # (Q, n)
    data_rad: FloatArray,  # (P, n), P >= 1
    periodic: BoolArray,  # (n,)
) -> tuple[FloatArray, IntArray]:  # (Q,) distance in rad, (Q,) index into data_rad
    """Joint-metric distance from each query configuration to its nearest in `data_rad`
    (periodic joints wrapped), and which one it is. Exact: the box around limited joints
    is wider than any distance between the points."""
    both = np.concatenate([query_rad, data_rad])  # (Q + P, n)
    span_rad = float(np.linalg.norm(both.max(axis=0) - both.min(axis=0)))
    box = JointBox.covering(both, periodic, margin_rad=span_rad + 1.0)
    distance_rad, index = box.tree(data_rad).query(box.points(query_rad))
    return np.asarray(distance_rad, dtype=np.float64), np.asarray(index, dtype=np.int64)


def coverage_distances(
    reference_rad: FloatArray,  # (P, n)
    returned_rad: FloatArray,  # (K, n)
    periodic: BoolArray,  # (n,)
) -> FloatArray:  # (P,)
    """Each reference configuration's joint-metric distance to the nearest returned one
    (inf when nothing was returned)."""
    if len(returned_rad) == 0:
        return np.full(len(reference_rad), np.inf)
    if len(reference_rad) == 0:
        return np.zeros(0)
    return nearest_reference(reference_rad, returned_rad, periodic)[0]


def _members(result: SmmResult, num_joints: int) -> list[FloatArray]:
    """Each component's returned configurations (K_c, n): accepted samples and path points."""
    members = []
    for component in result.components:
        q_rad = component.configurations_rad.reshape(-1, num_joints)
        if component.path is not None:
            q_rad = np.concatenate([q_rad, component.path.q_rad])
        members.append(q_rad)
    return members


def reference_answer(result: SmmResult, num_joints: int, redundancy: int) -> ReferenceAnswer:
    members = _members(result, num_joints)
    sizes = np.array([c.size for c in result.components], dtype=np.int64)  # (C,)
    accepted = result.counts.accepted
    counted = (
        np.ones(len(sizes), dtype=bool)
        if redundancy == 1
        else sizes >= MIN_COMPONENT_SHARE * max(accepted, 1)
    )
    return ReferenceAnswer(
        q_rad=np.concatenate([np.zeros((0, num_joints)), *members]),
        component=np.concatenate(
            [np.zeros(0, np.int64)] + [np.full(len(q), c) for c, q in enumerate(members)]
        ),
        counted=counted,
        accepted=accepted,
        total_ms=result.timings.total_ms,
    )


def agreement(
    result: SmmResult, reference: ReferenceAnswer, periodic: BoolArray
) -> TargetAgreement:
    """One candidate answer against the reference (the measures of docs/sweep.md)."""
    num_joints = len(periodic)
    members = _members(result, num_joints)
    returned = np.concatenate([np.zeros((0, num_joints)), *members])
    coverage = coverage_distances(reference.q_rad, returned, periodic)
    counted = reference.counted
    merges = 0
    if len(reference.q_rad) == 0:
        count_right, found = len(members) == 0, 0
    else:
        # (K,) the reference component of each returned configuration, split by component
        owner = reference.component[nearest_reference(returned, reference.q_rad, periodic)[1]]
        ends = np.cumsum([len(q) for q in members])[:-1]
        touched = [np.unique(on) for on in np.split(owner, ends) if len(on)]
        holders = np.zeros(len(counted), dtype=np.int64)  # (C,) returned components on each
        for on in touched:
            holders[on[counted[on]]] += 1
        extra_small = sum(int(not counted[on].any()) for on in touched)
        merges = sum(int(counted[on].sum() > 1) for on in touched)
        splits = int(((holders > 1) & counted).sum())
        count_right = (
            len(members) - extra_small == reference.counted_components and not merges + splits
        )
        found = int(((holders > 0) & counted).sum())
    return TargetAgreement(
        sampled=result.counts.sampled,
        accepted=result.counts.accepted,
        count_right=bool(count_right),
        merges=merges,
        found=found,
        counted=reference.counted_components,
        coverage_rad=coverage,
        stage_ms=stage_times_ms(result),
    )


def summarise(answers: Sequence[TargetAgreement]) -> Measures:
    """One candidate's measures over its targets' agreements."""
    counted = sum(a.counted for a in answers)
    coverage = np.concatenate([a.coverage_rad for a in answers])
    stage_ms = median_stage_ms([a.stage_ms for a in answers])
    return Measures(
        targets=len(answers),
        answered=sum(a.accepted > 0 for a in answers),
        keep_rate=sum(a.accepted for a in answers) / sum(a.sampled for a in answers),
        count_right=float(np.mean([a.count_right for a in answers])),
        merges_per_target=float(np.mean([a.merges for a in answers])),
        recall=sum(a.found for a in answers) / counted if counted else None,
        coverage_p95_rad=coverage_p95(coverage) if len(coverage) else None,
        median_total_ms=stage_ms["total"],
        median_stage_ms=stage_ms,
    )


@dataclass(frozen=True)
class SweepTargets:
    """The sweep's targets as the query's arguments."""

    fields: list[TargetFields]  # T


def sweep_targets(model: ServedModel, count: int, seed: int) -> SweepTargets:
    task = model.manifest.task
    drawn = held_out_targets(model, count, seed)
    return SweepTargets(
        fields=[fields_reached(task, drawn.position_m[i], drawn.rotation[i]) for i in range(count)]
    )


def answer(
    model: ServedModel, setting: Setting, targets: SweepTargets, i: int, seed: int
) -> SmmResult:
    candidate = with_defaults(
        model,
        sampler=setting.sampler,
        correction_steps=setting.correction_steps,
        num_samples=setting.num_samples,
        connectivity=connectivity_of(model, setting),
    )
    query = Query.for_model(
        candidate.manifest,
        position_m=targets.fields[i].position_m,
        orientation_wxyz=targets.fields[i].orientation_wxyz,
        axis=targets.fields[i].axis,
        seed=seed,
        check_self=False,  # the sweep weighs settings against the kinematic reference
    )
    return run(candidate, query)


def connectivity_of(model: ServedModel, setting: Setting) -> ConnectivitySpec:
    """The model's connectivity with the setting's step in the field its r uses."""
    field_name = connectivity_step_field(model.manifest.redundancy)
    return model.manifest.defaults.connectivity.model_copy(
        update={field_name: setting.connectivity_step_rad}
    )


def raw_error(
    model: ServedModel, sampler: SamplerSpec, targets: SweepTargets, num_samples: int, seed: int
) -> TimePowerRow:
    """The flow's raw samples (no correction) with `sampler`, over the targets (seed + i)."""
    manifest = model.manifest
    task = manifest.task
    limits = JointLimits.of(manifest.joints)
    errors = []
    for i, fields in enumerate(targets.fields):
        target = encode_target(
            task, manifest.condition, fields.position_m, fields.orientation_wxyz, fields.axis
        )
        q_raw = sample_configurations(
            velocity=model.network(sampler),
            condition=target.condition,
            num_samples=num_samples,
            sampler=sampler,
            joint_normalisation=manifest.joint_normalisation,
            limits=limits,
            rng=np.random.default_rng(seed + i),
        )
        errors.append(task_error_norms(model.kinematics(q_raw), target, task))
    raw = summarise_raw(
        sampler, np.stack([p for p, _ in errors]), np.stack([o for _, o in errors]),
        manifest.reach_m, bool(task.orientation_rows),
    )  # fmt: skip
    e_pct = raw.position_error_pct_reach_mean
    if raw.orientation_error_pct_mean is not None:
        e_pct = (e_pct + raw.orientation_error_pct_mean) / 2
    return TimePowerRow(
        time_power=sampler.time_power,
        raw_error_pct_reach=e_pct,
        raw_position_error_mm=raw.position_error_mm_mean,
    )
