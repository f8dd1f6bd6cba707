"""One method's answer to one target, as the report measures it: the service (flow +
DLS), the flow's raw samples, random-restart DLS, ssik's closed-form charts and the ODE
trace.

What a method returned is every configuration it hands a client: each component's
configurations and, for a 1-D SMM, the points of its ordered path, all labelled with
the component's index (a component that only the tracing found, with no accepted
sample, still counts through its path). The service and random-restart DLS decide
components with the same connect stage (`service.pipeline.connect.connect`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pytorch_kinematics as pk

from service.models.registry import ServedModel
from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.connect import connect
from service.pipeline.correction import task_error, task_error_norms
from service.pipeline.joint_space import JointLimits, joint_distance
from service.pipeline.run import into_limits, run, space_of
from service.pipeline.sampling import sample_configurations
from service.pipeline.targets import (
    Target,
    TargetFields,
    encode_target,
    fields_reached,
    target_reached,
)
from service.pipeline.types import ComponentPath, ComponentRoadmap, Correction, Query, Tolerance
from training.evaluate.baselines.ode import trace_smm
from training.evaluate.baselines.restart_dls import random_restart_dls
from training.evaluate.references.ssik_charts import chart_components
from training.evaluate.served import stage_times_ms


@dataclass
class MethodTarget:
    """One method's answer to one target."""

    raw_position_m: np.ndarray  # (S,) task-space error of every raw sample
    raw_orientation_rad: np.ndarray  # (S,) zeros when the task has no orientation
    returned: np.ndarray  # (K, n) returned configurations: members and path points
    returned_position_m: np.ndarray  # (K,)
    returned_orientation_rad: np.ndarray  # (K,)
    labels: np.ndarray | None  # (K,) component of each, None for the ODE trace
    sampled: int  # samples drawn (the denominator of the keep rate)
    time_ms: float
    stage_ms: dict[str, float] | None = None  # per timed span (the pipeline, the restarts)
    on_path: np.ndarray | None = None  # (K,) which returned rows are path points
    # (component index, its path), r = 1 only, in the order of the labels.
    paths: list[tuple[int, ComponentPath]] = field(default_factory=list)
    path_max_gap_rad: float | None = None  # largest step along any path (None: no path)
    near_singular: bool | None = None  # the connect stage's verdict (None: no connect stage)

    @property
    def component_count(self) -> int | None:
        """How many components the method returned; None when it labels none (the ODE)."""
        return None if self.labels is None else int(self.labels.max(initial=-1)) + 1

    @property
    def path_points(self) -> int:
        return 0 if self.on_path is None else int(self.on_path.sum())

    @property
    def kept(self) -> int:
        """Returned configurations that are accepted samples (path points left out)."""
        return len(self.returned) - self.path_points


def path_max_gap_rad(paths: Sequence[ComponentPath], periodic: BoolArray) -> float | None:
    """Largest joint-metric step between consecutive points of any path (last -> first too
    when the path is closed); None when there is no path."""
    gaps = [0.0]
    for path in paths:
        q = path.q_rad
        if len(q) > 1:
            gaps.append(float(joint_distance(q[1:], q[:-1], periodic).max()))
            if path.closed:
                gaps.append(float(joint_distance(q[-1], q[0], periodic)))
    return max(gaps) if paths else None


@dataclass(frozen=True)
class Returned:
    """Every configuration of an answer's components, labelled by component."""

    q_rad: FloatArray  # (K, n)
    labels: np.ndarray  # (K,) component index
    on_path: BoolArray  # (K,) a path point (not an accepted sample)
    paths: list[tuple[int, ComponentPath]]


def returned_points(
    components: Sequence[tuple[FloatArray, ComponentPath | None]], num_joints: int
) -> Returned:
    """Each component's (configurations (k, n), path) as one labelled array: its
    configurations, then its path points, labelled with the component's index."""
    blocks: list[FloatArray] = [np.zeros((0, num_joints))]
    labels: list[np.ndarray] = [np.zeros(0, int)]
    on_path: list[BoolArray] = [np.zeros(0, bool)]
    paths: list[tuple[int, ComponentPath]] = []
    for index, (q, path) in enumerate(components):
        pieces = [q] if path is None else [q, path.q_rad]
        for piece, is_path in zip(pieces, (False, True), strict=False):
            blocks.append(piece)
            labels.append(np.full(len(piece), index))
            on_path.append(np.full(len(piece), is_path))
        if path is not None:
            paths.append((index, path))
    return Returned(np.concatenate(blocks), np.concatenate(labels), np.concatenate(on_path), paths)


def _errors(model: ServedModel, q: FloatArray, target: Target) -> tuple[FloatArray, FloatArray]:
    if not len(q):
        return np.zeros(0), np.zeros(0)
    return task_error_norms(model.kinematics(q), target, model.manifest.task)


def _answered(
    model: ServedModel,
    target: Target,
    raw_p: FloatArray,
    raw_o: FloatArray,
    components: Sequence[tuple[FloatArray, ComponentPath | None]],
    num_samples: int,
    stages: dict[str, float],
    near_singular: bool,
) -> MethodTarget:
    """A method's components as the report measures them: every returned configuration
    (samples and path points), its errors, the path gaps, the near-singular flag."""
    returned = returned_points(components, model.manifest.joints.count)
    p, o = _errors(model, returned.q_rad, target)
    limits = model.limits
    return MethodTarget(
        raw_p, raw_o, returned.q_rad, p, o, returned.labels, num_samples, stages["total"],
        stages, returned.on_path, returned.paths,
        path_max_gap_rad([path for _, path in returned.paths], limits.periodic), near_singular,
    )  # fmt: skip


def flow_target(
    model: ServedModel, q_target: np.ndarray, num_samples: int, seed: int
) -> MethodTarget:
    """The service's answer (`served_target`) with the flow's raw samples' errors: the
    same draw as the pipeline's (same sampler, seed and count), sampled again untimed."""
    manifest = model.manifest
    answer = served_target(model, q_target, num_samples, seed)
    target = _target_of(model, q_target).encoded
    q_raw = sample_configurations(
        velocity=model.velocity,
        condition=target.condition,
        num_samples=num_samples,
        sampler=manifest.defaults.sampler,
        joint_normalisation=manifest.joint_normalisation,
        limits=JointLimits.of(manifest.joints),
        rng=np.random.default_rng(seed),
    )
    raw_p, raw_o = task_error_norms(model.kinematics(q_raw), target, manifest.task)
    return replace(answer, raw_position_m=raw_p, raw_orientation_rad=raw_o)


def served_target(
    model: ServedModel,
    q_target: np.ndarray,
    num_samples: int,
    seed: int,
    check_self: bool = False,
) -> MethodTarget:
    """The service's pipeline answer to the target q_target reaches, as a client asks it
    (position, quaternion); no raw-sample errors (empty), its time the pipeline's own.

    By default the kinematic fibre, as the exact references trace it: collisions aside
    (the report's scene section asks with them). `check_self`: self-collision checked too,
    as a request without options asks (on a model with collision geometry), for timing
    what a client waits for; its components are then the free pieces, not the fibre's."""
    target = _target_of(model, q_target)
    result = run(model, _served_query(model, target, num_samples, seed, check_self))
    none = np.zeros(0)
    components = [(c.configurations_rad, c.path) for c in result.components]
    # The keep rate's denominator: the samples drawn (fewer than num_samples where the
    # model draws in rounds and stops early).
    return _answered(
        model, target.encoded, none, none, components, result.counts.sampled,
        stage_times_ms(result), result.structure.near_singular,
    )  # fmt: skip


def served_roadmaps(
    model: ServedModel, q_target: np.ndarray, num_samples: int, seed: int
) -> list[ComponentRoadmap | None]:
    """The roadmap of each component of `served_target`'s answer (the same query, asked
    with its roadmaps), in the order of its labels; None for a traced component."""
    query = _served_query(model, _target_of(model, q_target), num_samples, seed, False)
    result = run(model, replace(query, include_roadmap=True))
    return [c.roadmap for c in result.components]


def _served_query(
    model: ServedModel, target: _Asked, num_samples: int, seed: int, check_self: bool
) -> Query:
    return Query.for_model(
        model.manifest, position_m=target.fields.position_m,
        orientation_wxyz=target.fields.orientation_wxyz, axis=target.fields.axis,
        num_samples=num_samples, seed=seed, include_paths=True, check_self=check_self,
    )  # fmt: skip


@dataclass(frozen=True)
class _Asked:
    """A target as a client sends it."""

    fields: TargetFields
    encoded: Target  # as the pipeline encodes it


def _target_of(model: ServedModel, q_target: np.ndarray) -> _Asked:
    manifest = model.manifest
    fk = model.kinematics(q_target[None])
    fields = fields_reached(manifest.task, fk.position_m[0], fk.rotation[0])
    encoded = encode_target(
        manifest.task, manifest.condition, fields.position_m, fields.orientation_wxyz, fields.axis
    )
    return _Asked(fields, encoded)


def raw_samples_target(answer: MethodTarget) -> MethodTarget:
    """The flow alone (FM): the service's raw samples, none returned, timed by its sampler."""
    return MethodTarget(
        raw_position_m=answer.raw_position_m,
        raw_orientation_rad=answer.raw_orientation_rad,
        returned=np.zeros((0, answer.returned.shape[1])),
        returned_position_m=answer.raw_position_m,
        returned_orientation_rad=answer.raw_orientation_rad,
        labels=None,
        sampled=len(answer.raw_position_m),
        time_ms=answer.stage_ms["sample"] if answer.stage_ms else float("nan"),
    )


def reference_target(model: ServedModel, q_target: np.ndarray) -> tuple[Target, np.ndarray]:
    """The target made by q_target (task axes; rotation for a pose task, the tool axis's
    direction for an axis task) and its 3-D position."""
    fk = model.kinematics(q_target[None])
    return target_reached(model.manifest.task, fk.position_m[0], fk.rotation[0]), fk.position_m[0]


def restart_target(
    model: ServedModel, chain: pk.SerialChain, q_target: np.ndarray, num_samples: int, seed: int
) -> MethodTarget:
    """Random-restart DLS, then the service's own stages after its correction: for r > 1
    the pull into the limits (`run.into_limits`, timed as "correct"), acceptance, and the
    connect stage with the model's connectivity defaults and coaxial sets; its time
    includes them."""
    manifest, defaults = model.manifest, model.manifest.defaults
    target, position_m = reference_target(model, q_target)
    solutions = random_restart_dls(
        chain, manifest.joints, manifest.task, position_m, target.rotation, num_samples, seed
    )
    space = space_of(model, target, Tolerance.of(defaults), CollisionCheck.none())
    q = space.limits.wrap(solutions.q_rad.astype(np.float64))
    fk = model.kinematics(q)
    raw_p, raw_o = task_error_norms(fk, target, manifest.task)
    jacobian = task_error(fk, target, manifest.task)[1]
    start = time.perf_counter()
    correction = into_limits(model, space, Correction(q, raw_p, raw_o, jacobian))
    pulled_s = time.perf_counter()
    acceptance = space.accept(correction)
    accepted_s = time.perf_counter()
    connection = connect(space, correction, acceptance, defaults.connectivity)
    connected_s = time.perf_counter()
    stages = {
        "solve": solutions.wall_time_ms,
        # r = 1: no pull; its check joins accept, so that the stages add up to the total
        **({"correct": (pulled_s - start) * 1e3} if manifest.redundancy > 1 else {}),
        "accept": (accepted_s - (pulled_s if manifest.redundancy > 1 else start)) * 1e3,
        "connect": (connected_s - accepted_s) * 1e3,
        "total": solutions.wall_time_ms + (connected_s - start) * 1e3,
    }
    return _answered(
        model, target, raw_p, raw_o, [(c.q_rad, c.path) for c in connection.components],
        num_samples, stages, connection.structure.near_singular,
    )  # fmt: skip


def ssik_target(model: ServedModel, q_target: np.ndarray) -> MethodTarget:
    """ssik's closed-form charts of a full pose (references/ssik_charts.py), cut to the
    model's limits, as components: the points along every in-limit arc at the path
    spacing, labelled by the glued arcs. Its time is the charts' and their in-limit
    intervals' (ssik's answer); the points, which the figures need, are timed apart
    ("points")."""
    manifest = model.manifest
    target, _ = reference_target(model, q_target)
    fk = model.kinematics(q_target[None])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = fk.rotation[0], fk.position_m[0]
    limits = model.limits
    spacing = manifest.defaults.connectivity.path_spacing_rad
    charted = chart_components(manifest.robot, pose, limits.lower_rad, limits.upper_rad, spacing)
    count = int(charted.component.max(initial=-1)) + 1
    components = [(charted.q_rad[charted.component == c], None) for c in range(count)]
    stages = {"solve": charted.charts_ms, "points": charted.points_ms, "total": charted.charts_ms}
    p, o = _errors(model, charted.q_rad, target)
    return _answered(model, target, p, o, components, len(charted.q_rad), stages, False)


def ode_target(model: ServedModel, q_target: np.ndarray) -> MethodTarget:
    manifest = model.manifest
    trace = trace_smm(model.kinematics, manifest.task, q_target)
    target, _ = reference_target(model, q_target)
    p, o = task_error_norms(model.kinematics(trace.q_rad), target, manifest.task)
    return MethodTarget(p, o, trace.q_rad, p, o, None, len(trace.q_rad), trace.wall_time_ms)
