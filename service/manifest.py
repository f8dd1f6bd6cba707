"""The model's file formats: what `models/<model-id>/manifest.json` and `chain.json` record.

One schema per file, written by `training.export` and read by `service.models.registry`.
The manifest holds everything needed to use a model (joints, task, condition layout,
normalisation, defaults) and to trust it (training budget, measured quality, sha256 of
every file). chain.json is the robot's serial chain as read from the URDF: the data of
the numpy kinematics kernel (`service.models.chain`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, model_validator

# The bundled models: models/<model-id>/ beside service/ and training/ in the repository.
REPO_MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
MANIFEST_FILE = "manifest.json"
FLOW_FILE = "flow.onnx"
FLOW_INT8_FILE = "flow_int8.onnx"
REFLOW_FILE = "reflow.onnx"
REFLOW_INT8_FILE = "reflow_int8.onnx"
KINEMATICS_FILE = "kinematics.onnx"
CHAIN_FILE = "chain.json"
COLLISION_FILE = "collision.json"


def bundled_model_ids() -> list[str]:
    """The model ids under REPO_MODELS_DIR (each a directory with a manifest), sorted."""
    return sorted(p.name for p in REPO_MODELS_DIR.iterdir() if (p / MANIFEST_FILE).exists())


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class JointSpec(_Strict):
    """Joint names in model order, limits in rad, and which joints are full circles."""

    names: list[str]
    lower_rad: list[float]
    upper_rad: list[float]
    periodic: list[bool] = Field(
        description="True for joints whose range covers the full circle; only these are wrapped."
    )

    @model_validator(mode="after")
    def _same_lengths(self) -> JointSpec:
        n = len(self.names)
        if not (len(self.lower_rad) == len(self.upper_rad) == len(self.periodic) == n):
            raise ValueError("joints: names, lower_rad, upper_rad and periodic differ in length")
        return self

    @property
    def count(self) -> int:
        return len(self.names)


TaskName = Literal["position", "pose", "axis"]
# The end-effector axis the axis task points when its robot file names none: z, the
# approach axis of a flange or tool frame (ROS REP 103's convention for tools).
DEFAULT_TOOL_AXIS = (0.0, 0.0, 1.0)
# A tool axis is normalised when its norm is within this of 1, refused otherwise.
TOOL_AXIS_NORM_TOLERANCE = 1e-6


class TaskSpec(_Strict):
    """Which components of the end-effector pose the task constrains.

    position_axes: base-frame axes of the end-effector position that are
    constrained ([0, 1] for a planar arm, [0, 1, 2] in space); orientation:
    whether the full orientation is constrained as well (the pose task);
    tool_axis: the axis task's unit vector fixed in the end-effector frame, whose
    direction in the base frame is constrained while the rotation about it is free
    (drilling, welding, suction, spraying: 2 task coordinates, not 3).
    """

    name: TaskName
    position_axes: list[int]
    orientation: bool
    tool_axis: list[float] | None = Field(
        default=None,
        description="axis task only: the tool axis in the end-effector frame (unit)",
    )

    @model_validator(mode="after")
    def _one_orientation(self) -> TaskSpec:
        if (self.name == "axis") != (self.tool_axis is not None):
            raise ValueError("task: tool_axis is given for the axis task and only for it")
        if self.orientation and self.tool_axis is not None:
            raise ValueError("task: orientation (pose) and tool_axis (axis) exclude each other")
        if self.tool_axis is not None:
            norm = math.hypot(*self.tool_axis)
            if len(self.tool_axis) != 3 or not abs(norm - 1.0) <= TOOL_AXIS_NORM_TOLERANCE:
                raise ValueError(f"task: tool_axis must be 3 values of norm 1: {self.tool_axis}")
        return self

    @property
    def orientation_rows(self) -> int:
        """The task coordinates of the orientation: 3 (pose), 2 (axis) or 0 (position)."""
        return 3 if self.orientation else 2 if self.tool_axis is not None else 0

    @property
    def dimension(self) -> int:
        """m, the number of task coordinates."""
        return len(self.position_axes) + self.orientation_rows


class AffineNormalisation(_Strict):
    """value_normalised = (value - offset) / scale, per dimension."""

    offset: list[float]
    scale: list[float]

    def normalise(self, value: NDArray[np.float64]) -> NDArray[np.float64]:
        return (value - np.asarray(self.offset)) / np.asarray(self.scale)

    def denormalise(self, value: NDArray[np.float64]) -> NDArray[np.float64]:
        return value * np.asarray(self.scale) + np.asarray(self.offset)


class ConditionSpec(_Strict):
    """Layout of the flow's condition vector and its normalisation."""

    names: list[str]
    normalisation: AffineNormalisation


Precision = Literal["float32", "int8"]
# Which trained field: "base", the flow trained by smm-train; "reflow", that flow reflowed
# for few-step sampling (training/reflow.py).
FlowKind = Literal["base", "reflow"]
# The flow network file of each field and precision: the float32 export, and its int8
# dynamic quantisation (training/quantise.py), same inputs and outputs.
FLOW_FILES: dict[tuple[str, str], str] = {
    ("base", "float32"): FLOW_FILE,
    ("base", "int8"): FLOW_INT8_FILE,
    ("reflow", "float32"): REFLOW_FILE,
    ("reflow", "int8"): REFLOW_INT8_FILE,
}


class SamplerSpec(_Strict):
    """How stage 2 integrates the flow: explicit Euler over the time grid
    t_k = 1 - (1 - k / steps) ** time_power (service/pipeline/sampling.py), with the
    flow network of `flow` and `precision` (`file`)."""

    method: Literal["euler"] = "euler"
    flow: FlowKind = Field(
        default="base",
        description="base: the flow trained by smm-train; reflow: that flow reflowed for "
        "few-step sampling (training/reflow.py: straight paths from noise to the base "
        "flow's own endpoints), chosen by the sweep when its samples are as good",
    )
    precision: Precision = Field(
        default="float32",
        description="float32: flow.onnx as trained; int8: flow_int8.onnx, its weights "
        "quantised to int8 with activations quantised per batch (onnxruntime dynamic "
        "quantisation), chosen by the sweep when its samples are as good",
    )
    steps: int = Field(ge=1)
    time_power: float = Field(
        default=1.0,
        ge=1.0,
        le=4.0,
        description="1: uniform steps (the paper's); above 1 the steps shorten towards t = 1, "
        "where the learned field turns fastest (EDM's rho schedule, in flow time)",
    )
    round_samples: int | None = Field(
        default=None,
        ge=1,
        description="r = 1 only: draw this many samples at a time and stop after a round "
        "whose accepted samples all lie on curves already traced (service/pipeline/"
        "rounds.py), num_samples at most; None: all num_samples at once",
    )
    call_rows: int | None = Field(
        default=None,
        ge=1,
        description="evaluate the network on at most this many samples per call: the "
        "samples (of each round) are integrated in equal chunks of at most call_rows, each "
        "on its own (int8: its activation scales from its own rows), the chunks over the "
        "request's row threads, each on one onnxruntime thread "
        "(service/pipeline/sampling.py); None: all at once, one call per step",
    )

    @property
    def file(self) -> str:
        """The flow network file this sampler evaluates."""
        return FLOW_FILES[(self.flow, self.precision)]


class ConnectivitySpec(_Strict):
    """Stage 5 parameters: the projected local planner, its roadmap and r = 1 tracing."""

    # Projected local planner (OMPL ProjectedStateSpace: delta 0.05, lambda 2, tol 1e-4).
    delta_rad: float = Field(gt=0)
    lambda_: float = Field(gt=1)
    projection_tolerance: float = Field(gt=0)
    # Roadmap candidate edges.
    neighbours: int = Field(ge=1)
    radius_rad: float = Field(gt=0)
    bridge_radius_rad: float = Field(gt=0)
    bridge_pairs: int = Field(ge=0)
    bridge_lambda: float = Field(gt=1)
    limit_check_rad: float | None = Field(
        default=None,
        gt=0,
        description="the spacing at which the roadmap's walks also check each step against "
        "the joint limits between its ends (FibreSpace.inside_between); None: each step is "
        "checked where it lands, OMPL's check, which can step over a sliver of the fibre "
        "outside the limits",
    )
    # r = 1 tracing.
    trace_step_rad: float = Field(gt=0)
    trace_max_steps: int = Field(ge=1)
    seed_spacing_rad: float = Field(gt=0)
    path_spacing_rad: float = Field(gt=0)
    # sigma_min(J) below this on the fibre: the target is near a singular value.
    singular_sigma: float = Field(ge=0)


class Defaults(_Strict):
    """Serving defaults, chosen by measurement; `reasons` says why each has its value."""

    num_samples: int = Field(ge=1)
    sampler: SamplerSpec
    correction_steps: int = Field(ge=0)
    damping: float = Field(gt=0)
    connectivity: ConnectivitySpec
    tolerance_position_m: float = Field(gt=0)
    tolerance_orientation_rad: float = Field(gt=0)
    reasons: dict[str, str]


class TrainingRecord(_Strict):
    """Provenance: how the flow was trained and by which command."""

    command: str
    samples: int
    epochs: int
    batch_size: int
    device: str
    wall_time_s: float
    best_validation_loss: float
    best_epoch: int
    torch_version: str
    git_commit: str = Field(description="the commit the training run started from")
    export_git_commit: str | None = Field(
        default=None,
        description="the commit that exported, swept and measured the model, when not the "
        "training's (smm-train --from-checkpoint re-exports a run's best.pt with newer code)",
    )
    config: dict[str, object]
    processor: dict[str, object] | None = Field(
        default=None,
        description="the processor that trained it (cpu, generation, dot_product, cores; "
        "training.machine): the same command and commit give the same weights on it, and "
        "may give other weights on another, where PyTorch's CPU kernels round otherwise. "
        "None for a model trained before manifests recorded it",
    )


class RawError(_Strict):
    """Task error of uncorrected flow samples, over all samples (not only kept ones).

    e_p in % is |p - p*| / reach; e_o in % is the geodesic angle / pi (the paper's metrics).
    """

    sampler_steps: int
    sampler_flow: FlowKind = "base"  # which trained field (SamplerSpec.flow)
    sampler_time_power: float = 1.0  # the Euler grid's power (SamplerSpec.time_power)
    sampler_precision: Precision = "float32"  # the flow network's (SamplerSpec.precision)
    position_error_mm_mean: float
    position_error_mm_median: float
    position_error_pct_reach_mean: float
    orientation_error_deg_mean: float | None
    orientation_error_deg_median: float | None
    orientation_error_pct_mean: float | None
    # The paper's own figures, to read beside its tables: means over the samples whose
    # e = (e_p + e_o) / 2 (e = e_p for a position task) is under PAPER_KEPT_BELOW = 0.02,
    # and that fraction of all samples; and the mean over targets of the best sample's e_p
    # (its 4-D figure). None in manifests written before they were measured.
    kept_only_fraction: float | None = None
    kept_only_position_error_pct_reach_mean: float | None = None
    kept_only_orientation_error_pct_mean: float | None = None
    best_of_n_position_error_pct_reach_mean: float | None = None


class Quality(_Strict):
    """Measured on held-out targets (FK of random configurations, fixed seed)."""

    held_out_targets: int
    samples_per_target: int
    raw: list[RawError] = Field(
        description="First at the serving default sampler, then at the paper's 100 Euler steps."
    )
    keep_rate: float = Field(
        description="Fraction of raw samples accepted after the default correction."
    )
    targets_with_solution: float
    measured_by: str


# A 4x4 homogeneous transform, row-major: [[R, t], [0, 0, 0, 1]].
Transform = list[list[float]]
# Rotation blocks of the URDF's origins are orthonormal to rounding (float64 cos and sin).
_ORTHONORMAL_TOLERANCE = 1e-12


def _check_transform(name: str, value: Transform) -> None:
    matrix = np.asarray(value, dtype=np.float64)
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise ValueError(f"{name}: not a finite 4x4 transform")
    if not np.array_equal(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"{name}: last row is {matrix[3].tolist()}, not [0, 0, 0, 1]")
    rotation = matrix[:3, :3]
    error = float(np.max(np.abs(rotation @ rotation.T - np.eye(3))))
    if not error <= _ORTHONORMAL_TOLERANCE or np.linalg.det(rotation) < 0:
        raise ValueError(f"{name}: rotation block is not a rotation (R R^T - I up to {error:.3g})")


class ChainJoint(_Strict):
    """One movable joint (revolute or continuous) of the serial chain."""

    name: str
    origin: Transform = Field(
        description="Fixed transform from the previous joint's frame (the base frame for the "
        "first joint) to this joint's frame at q = 0; the fixed joints between them folded in."
    )
    axis: list[float] = Field(description="Unit rotation axis in this joint's frame.")


class ChainSpec(_Strict):
    """chain.json: the serial chain from the base to the end effector, in float64.

    FK(q) = origin_1 Rot(axis_1, q_1) origin_2 Rot(axis_2, q_2) ... origin_n Rot(axis_n, q_n)
    tip, the end-effector pose in the base frame. Written at export from the URDF as read
    by `training.kinematics.load_chain`, so it is the chain kinematics.onnx was exported
    from.
    """

    format_version: Literal[1] = 1
    base_link: str
    end_effector_link: str
    joints: list[ChainJoint] = Field(min_length=1, description="In the model's joint order.")
    tip: Transform = Field(
        description="Fixed transform from the last joint's frame to the end-effector link."
    )

    @model_validator(mode="after")
    def _transforms_and_axes(self) -> ChainSpec:
        for joint in self.joints:
            _check_transform(f"joint {joint.name!r} origin", joint.origin)
            axis = np.asarray(joint.axis, dtype=np.float64)
            if axis.shape != (3,) or not abs(float(np.linalg.norm(axis)) - 1.0) <= 1e-12:
                raise ValueError(f"joint {joint.name!r} axis {joint.axis} is not a unit 3-vector")
        _check_transform("tip", self.tip)
        return self

    @property
    def joint_names(self) -> list[str]:
        return [joint.name for joint in self.joints]


class FileRef(_Strict):
    path: str = Field(description="Relative to the models directory.")
    sha256: str


# Why a pair of bodies is never checked against each other (MoveIt's setup assistant's
# reasons): joined by a joint ("adjacent"), in collision at the default configuration
# ("default": each joint at 0, or mid-range where 0 is outside its limits), in collision
# in (almost) every sampled configuration ("always"), in none of them ("never"), or named
# by the robot's SRDF ("srdf").
DisabledReason = Literal["adjacent", "default", "always", "never", "srdf"]


class CollisionBody(_Strict):
    """Spheres covering one URDF link's collision geometry, in the frame it moves with,
    and inside each sphere the convex hull of the geometry it holds.

    Every point of the link's `<collision>` geometry (primitives and meshes) lies inside
    at least one sphere, so a distance between spheres is never more than the distance
    between the geometry they cover: a check on the spheres is conservative. Each sphere
    also holds the convex hull (grown by a pad) of the part of the geometry assigned to
    it, and those parts together are the whole geometry: the hulls are a tighter cover,
    and the check measures them where the spheres alone would call a configuration not
    free (`service.pipeline.collision.convex`). Without hulls, each sphere is its own.
    """

    link: str
    frame: int = Field(
        ge=0,
        description="0: the base frame (the body does not move); k in 1..n: the frame of "
        "chain joint k as chain.json defines it (origin_1 Rot(axis_1, q_1) ... origin_k "
        "Rot(axis_k, q_k), the URDF frame of joint k's child link)",
    )
    centres_m: list[list[float]] = Field(min_length=1, description="(S, 3) in that frame")
    radii_m: list[float] = Field(min_length=1, description="(S,)")
    hulls_m: list[list[list[float]]] = Field(
        default_factory=list,
        description="S lists of (V_s, 3) vertices in that frame, or none: the convex hull "
        "of the geometry sphere s holds",
    )
    hull_pads_m: list[float] = Field(
        default_factory=list,
        description="(S,) or none: the radius each hull is grown by (0 for meshes, boxes "
        "and cylinders; a capsule's or sphere's radius)",
    )

    @model_validator(mode="after")
    def _spheres(self) -> CollisionBody:
        centres = np.asarray(self.centres_m, dtype=np.float64)
        radii = np.asarray(self.radii_m, dtype=np.float64)
        if centres.shape != (len(radii), 3) or not np.all(np.isfinite(centres)):
            raise ValueError(f"body {self.link!r}: centres_m must be finite (S, 3), S = radii")
        if not np.all(np.isfinite(radii)) or not np.all(radii > 0):
            raise ValueError(f"body {self.link!r}: radii_m must be finite and positive")
        if not self.hulls_m and not self.hull_pads_m:
            return self
        if len(self.hulls_m) != len(radii) or len(self.hull_pads_m) != len(radii):
            raise ValueError(f"body {self.link!r}: hulls_m and hull_pads_m need one per sphere")
        for s, (hull, pad) in enumerate(zip(self.hulls_m, self.hull_pads_m, strict=True)):
            vertices = np.asarray(hull, dtype=np.float64)
            if vertices.ndim != 2 or vertices.shape[1:] != (3,) or not len(vertices):
                raise ValueError(f"body {self.link!r}: hull {s} must be (V, 3) vertices, V > 0")
            if not np.all(np.isfinite(vertices)) or not (math.isfinite(pad) and pad >= 0):
                raise ValueError(f"body {self.link!r}: hull {s} must be finite, its pad >= 0")
            reach = np.linalg.norm(vertices - centres[s], axis=1).max() + pad
            if reach > radii[s] * (1 + 1e-9) + 1e-12:
                raise ValueError(
                    f"body {self.link!r}: hull {s} reaches {reach:.6g} m from its sphere's "
                    f"centre, past its radius {radii[s]:.6g} m"
                )
        return self


class DisabledPair(_Strict):
    """Two bodies whose collision is never checked, and why."""

    links: tuple[str, str]
    reason: DisabledReason


class CollisionSpec(_Strict):
    """collision.json: the robot's collision model, built at training time from its URDF
    (`training.collision`): the bodies on the chain and fixed to it, as spheres, and the
    pairs never checked. A body pair not listed is checked for self-collision."""

    format_version: Literal[1] = 1
    bodies: list[CollisionBody] = Field(
        description="Every link on the chain or fixed to it that has collision geometry."
    )
    disabled_pairs: list[DisabledPair]

    @model_validator(mode="after")
    def _pairs_name_bodies(self) -> CollisionSpec:
        names = [body.link for body in self.bodies]
        if len(set(names)) != len(names):
            raise ValueError("bodies: a link is listed twice")
        for pair in self.disabled_pairs:
            unknown = [link for link in pair.links if link not in names]
            if unknown:
                raise ValueError(f"disabled pair {pair.links}: no body {unknown}")
        return self


class CollisionRecord(_Strict):
    """Provenance of collision.json: how the spheres and the disabled pairs were made."""

    command: str
    urdf_sha256: str = Field(description="the URDF whose <collision> geometry it covers")
    srdf: FileRef | None = Field(description="the SRDF whose disable_collisions it reads")
    sphere_count: int
    configurations_sampled: int = Field(
        description="random configurations the 'always' and 'never' pairs were decided on "
        "(with coal, on the URDF's own geometry), and the free space measured on"
    )
    free_space_lost_fraction: float = Field(
        description="of those configurations free of self-collision on the URDF's geometry "
        "(outside the disabled pairs), the fraction the service's check (the spheres, then "
        "the hulls) calls in collision"
    )
    wall_time_s: float
    git_commit: str


class ReflowRecord(_Strict):
    """Provenance of reflow.onnx and reflow_int8.onnx (training/reflow.py)."""

    command: str
    config: dict[str, object]
    teacher_sha256: str = Field(description="flow.onnx, the base flow that taught the reflow")
    device: str
    teacher_wall_time_s: float = Field(description="integrating the teacher pairs")
    wall_time_s: float = Field(description="training the reflowed field")
    best_step: int
    one_step_endpoint_error: float = Field(
        description="mean squared distance, in normalised joint units, of the one-step "
        "endpoint from the teacher's on held-out pairs, at best_step"
    )
    torch_version: str
    git_commit: str = Field(description="the commit the reflow was trained and exported at")
    export_git_commit: str | None = Field(
        default=None,
        description="the commit that last swept, judged and measured the committed reflow "
        "again (smm-train reflow --export-only), when it did",
    )
    base_sampler: SamplerSpec | None = Field(
        default=None,
        description="the base flow's sampler the model served before the reflow (what the "
        "sweep weighed the reflowed sampler against; tools/benchmark.py times both)",
    )
    processor: dict[str, object] | None = Field(
        default=None,
        description="the processor that trained the reflow (as TrainingRecord.processor); "
        "None for a reflow trained before manifests recorded it",
    )


class Manifest(_Strict):
    format_version: Literal[1] = 1
    model_id: str
    robot: str
    task: TaskSpec
    urdf: FileRef
    end_effector_link: str
    reach_m: float = Field(
        description="L, the reach used to express errors in % (paper): the largest distance "
        "of the end effector from the base-link origin within the joint limits, measured at "
        "export (training.kinematics.measured_reach_m)."
    )
    joints: JointSpec
    joint_normalisation: AffineNormalisation
    condition: ConditionSpec
    files: dict[str, str] = Field(description="File name in the model directory -> sha256.")
    defaults: Defaults
    training: TrainingRecord
    reflow: ReflowRecord | None = None
    collision: CollisionRecord | None = Field(
        default=None,
        description="collision.json's provenance; None when the URDF has no collision "
        "geometry (answers then say that no self-collision was checked)",
    )
    quality: Quality | None = None
    created_utc: str

    @property
    def redundancy(self) -> int:
        """r = n - m."""
        return self.joints.count - self.task.dimension
