"""The pipeline's vocabulary: what goes in (`Query`), what each stage hands the next, what
comes out (`SmmResult`), and the model interfaces the stages call (Protocols).

Read in data-flow order: Query -> Target (targets.py) -> samples -> Correction ->
Acceptance -> Component -> ComponentSummary -> SmmResult. The loaded models
(`service.models`) implement `SmmModel`; the pipeline never imports them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol, cast, get_args, runtime_checkable

import numpy as np

from service.errors import RequestFieldError
from service.manifest import Defaults, Manifest
from service.pipeline.arrays import BoolArray, Float32Array, FloatArray, IntArray
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.collision.scene import Obstacle, Scene
from service.pipeline.joint_space import JointLimits
from service.pipeline.targets import validate_target

# The stages in the order run() calls them; timings, metrics and the response use these.
Stage = Literal["encode", "sample", "correct", "accept", "connect", "summarise"]
STAGES: tuple[Stage, ...] = get_args(Stage)
# What a response times: every stage, and the whole run.
TimedSpan = Literal[Stage, "total"]
TIMED_SPANS: tuple[TimedSpan, ...] = (*STAGES, "total")


# -- the models the stages call ------------------------------------------------------------


class VelocityField(Protocol):
    """The learned velocity v(q_t, t, condition) in normalised joint coordinates."""

    def __call__(
        self,
        q_t: Float32Array,  # (B, n)
        t: Float32Array,  # (B, 1)
        condition: Float32Array,  # (B, c)
    ) -> Float32Array:  # (B, n)
        ...


@dataclass(frozen=True)
class KinematicsResult:
    """Forward kinematics and geometric Jacobian (base frame, linear rows first)."""

    position_m: FloatArray  # (B, 3)
    rotation: FloatArray  # (B, 3, 3)
    jacobian: FloatArray  # (B, 6, n)


class Kinematics(Protocol):
    def __call__(self, q_rad: FloatArray) -> KinematicsResult:  # q_rad (B, n), float64
        ...


@runtime_checkable
class ChainKinematics(Kinematics, Protocol):
    """Kinematics of a serial chain the compiled kernels can evaluate themselves
    (`native.task_residual`): joint i's fixed transform with its axis turned onto z, and
    the tip (service/models/chain.py)."""

    fixed: FloatArray  # (n, 4, 4)
    tip: FloatArray  # (4, 4)


def chain_of(kinematics: Kinematics) -> ChainKinematics | None:
    """`kinematics` where it is a ChainKinematics (it has the chain's `fixed` and `tip`),
    else None: the Protocol's isinstance without its cost (tens of microseconds a call, a
    few dozen calls an answer)."""
    if hasattr(kinematics, "fixed") and hasattr(kinematics, "tip"):
        return cast(ChainKinematics, kinematics)
    return None


@dataclass(frozen=True)
class CoaxialSet:
    """Configurations with q_j = angle_rad, where joints j - 1 and j + 1 share one axis line
    (connect/coaxial.py finds them once per model): q + a slide stays on every fibre for any a."""

    joint: int  # j, whose angle aligns the two axes
    angle_rad: float  # q_j on the set, inside joint j's limits
    slide: FloatArray  # (n,) e_i - sign e_k: the exact self-motion along the set

    @property
    def moving(self) -> tuple[int, int]:
        """(i, k): the two joints the slide turns."""
        i, k = np.flatnonzero(self.slide)
        return int(i), int(k)


class SmmModel(Protocol):
    """What the pipeline needs of a served model: its manifest, flow and kinematics, its
    joint limits, the coaxial sets of its chain, and its bodies as spheres (None when its
    URDF has no collision geometry), made once when the model is loaded; and how many
    threads a compiled call's rows may be split over (rows.py)."""

    @property
    def manifest(self) -> Manifest: ...

    @property
    def velocity(self) -> VelocityField: ...

    @property
    def kinematics(self) -> Kinematics: ...

    @property
    def limits(self) -> JointLimits: ...

    @property
    def coaxial_sets(self) -> Sequence[CoaxialSet]: ...

    @property
    def robot_spheres(self) -> RobotSpheres | None: ...

    @property
    def row_threads(self) -> int: ...


# -- in: one query -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Query:
    """One target's request, checked against its model, with the model's defaults filled in.

    Build it with `Query.for_model`, the one constructor every caller uses (the route,
    the evaluation, the tests): a Query is valid for its model by construction, so the
    stages check nothing again.
    """

    position_m: list[float]  # (m_p,) the task's constrained position axes
    orientation_wxyz: tuple[float, float, float, float] | None  # pose task only
    axis: tuple[float, float, float] | None  # axis task only: the tool axis's direction
    num_samples: int
    seed: int
    tolerance_position_m: float
    tolerance_orientation_rad: float
    reference_rad: FloatArray | None  # (n,)
    max_configurations_per_component: int | None
    include_paths: bool  # r = 1: return each component's ordered path
    include_roadmap: bool  # return the roadmap of each component the roadmap decided
    scene: Scene  # the request's obstacles, base frame
    check_self: bool  # self-collision asked for (checked where the model has bodies)
    margin_m: float  # the least clearance a valid configuration keeps

    @property
    def tolerance(self) -> Tolerance:
        return Tolerance(self.tolerance_position_m, self.tolerance_orientation_rad)

    @classmethod
    def for_model(
        cls,
        manifest: Manifest,
        *,
        position_m: Sequence[float],
        orientation_wxyz: tuple[float, float, float, float] | None = None,
        axis: tuple[float, float, float] | None = None,
        num_samples: int | None = None,
        seed: int = 0,
        tolerance_position_m: float | None = None,
        tolerance_orientation_rad: float | None = None,
        reference_rad: Sequence[float] | None = None,
        max_configurations_per_component: int | None = None,
        include_paths: bool = True,
        include_roadmap: bool = False,
        obstacles: Sequence[Obstacle] = (),
        check_self: bool = True,
        margin_m: float = 0.0,
    ) -> Query:
        """Check the request's shape against the model (RequestFieldError names the field)
        and fill every option left as None from the model's defaults."""
        task, defaults = manifest.task, manifest.defaults
        validate_target(task, list(position_m), orientation_wxyz, axis)
        if tolerance_orientation_rad is not None and not task.orientation_rows:
            raise RequestFieldError(
                ("body", "tolerance", "orientation"),
                "tolerance.orientation applies only to the pose and axis tasks",
            )
        if reference_rad is not None and len(reference_rad) != manifest.joints.count:
            raise RequestFieldError(
                ("body", "reference_configuration"),
                f"reference_configuration must have {manifest.joints.count} values (one per "
                f"joint), got {len(reference_rad)}",
            )
        return cls(
            position_m=list(position_m),
            orientation_wxyz=orientation_wxyz,
            axis=axis,
            num_samples=defaults.num_samples if num_samples is None else num_samples,
            seed=seed,
            tolerance_position_m=(
                defaults.tolerance_position_m
                if tolerance_position_m is None
                else tolerance_position_m
            ),
            tolerance_orientation_rad=(
                defaults.tolerance_orientation_rad
                if tolerance_orientation_rad is None
                else tolerance_orientation_rad
            ),
            reference_rad=(
                None if reference_rad is None else np.asarray(reference_rad, dtype=np.float64)
            ),
            max_configurations_per_component=max_configurations_per_component,
            include_paths=include_paths,
            include_roadmap=include_roadmap,
            scene=Scene(tuple(obstacles)),
            check_self=check_self,
            margin_m=margin_m,
        )


# -- between the stages ------------------------------------------------------------------------


@dataclass(frozen=True)
class Tolerance:
    """The largest task error an answer's configuration may have (the query's)."""

    position_m: float
    orientation_rad: float  # the axis angle for the axis task; a position task's errors are 0

    @classmethod
    def of(cls, defaults: Defaults) -> Tolerance:
        """A model's default tolerance."""
        return cls(defaults.tolerance_position_m, defaults.tolerance_orientation_rad)

    def within(self, position_error_m: FloatArray, orientation_error_rad: FloatArray) -> BoolArray:
        """(N,) which errors (N,), (N,) are within it; NaN and inf are not."""
        return (position_error_m <= self.position_m) & (
            orientation_error_rad <= self.orientation_rad
        )


@dataclass(frozen=True)
class Correction:
    """Stage 3 output: configurations after DLS and their remaining task errors."""

    q_rad: FloatArray  # (N, n); periodic joints wrapped to (-pi, pi]
    position_error_m: FloatArray  # (N,) inf where the sample was not finite
    orientation_error_rad: FloatArray  # (N,) zeros for a position task
    jacobian: FloatArray  # (N, m, n) task Jacobian at q_rad (NaN where not finite)


@dataclass(frozen=True)
class Acceptance:
    """Stage 4 output: which samples are valid solutions, and why the others are not."""

    within_tolerance: BoolArray  # (N,)
    within_limits: BoolArray  # (N,)
    collision_free: BoolArray  # (N,) True where nothing was checked (kinematically invalid rows)
    # (N,) each sample's clearance where it was checked (on the fibre), NaN elsewhere;
    # None when collisions are not checked. Kept so that no later stage measures it again.
    clearance_m: FloatArray | None = None

    @property
    def on_fibre(self) -> BoolArray:
        """Within tolerance and inside the limits: on the fibre, collisions aside."""
        return self.within_tolerance & self.within_limits

    @property
    def accepted(self) -> BoolArray:
        return self.within_tolerance & self.within_limits & self.collision_free

    def kinematic(self) -> Acceptance:
        """The same samples judged without collisions (what the r = 1 trace starts from);
        the clearances measured stay, for the pieces cut from the curves."""
        return Acceptance(
            self.within_tolerance,
            self.within_limits,
            np.ones_like(self.collision_free),
            self.clearance_m,
        )


# Why an open 1-D component ends: at a joint limit, or where the curve enters collision.
EndReason = Literal["joint_limit", "collision"]


@dataclass(frozen=True)
class ComponentPath:
    """A 1-D component whole: its configurations in order along the curve."""

    q_rad: FloatArray  # (P, n) consecutive points at most the path spacing apart
    position_error_m: FloatArray  # (P,)
    orientation_error_rad: FloatArray  # (P,)
    closed: bool  # a whole loop inside the limits: the last point joins the first
    arc_length_rad: float  # joint-metric length of the path (with the closing gap if closed)
    ends: tuple[EndReason, EndReason] = ("joint_limit", "joint_limit")  # first, last; if open
    clearance_m: FloatArray | None = None  # (P,) when collisions were checked along it


@dataclass(frozen=True)
class ComponentRoadmap:
    """A component the roadmap decided, as a graph a planner can move along.

    Nodes: the component's members, in their order, then the nodes the connect stage added
    to join them (where steering walks ended, on coaxial sets); every node reaches the
    target within the query's tolerance and is valid (inside the limits, free when
    collisions are checked). Edges: node pairs joined by a motion the connect stage
    checked on the fibre, every step projected within the connectivity's projection
    tolerance and valid. The edges join any two nodes: the graph is connected.
    """

    q_rad: FloatArray  # (M, n) members first
    edges: IntArray  # (E, 2) node pairs, the lower index first, each pair once


@dataclass(frozen=True)
class Component:
    """Stage 5 output: one connected component of the fibre within the limits (an SMM).

    `q_rad` holds the accepted samples on it (none for a 1-D component that only the
    tracing found); `path` is the whole component in order (r = 1 only); `roadmap` the
    graph that joined its members (components the roadmap decided: r > 1, and r = 1
    samples on no traced curve).
    """

    q_rad: FloatArray  # (k, n) every accepted member
    position_error_m: FloatArray  # (k,)
    orientation_error_rad: FloatArray  # (k,)
    path: ComponentPath | None = None
    clearance_m: FloatArray | None = None  # (k,) the members', when already measured
    roadmap: ComponentRoadmap | None = None


@dataclass(frozen=True)
class FibreStructure:
    """How sure the component structure is: near a singular value it may be ambiguous."""

    near_singular: bool  # sigma_min(J) small, a curve not traced through, strands too close
    min_singular_value: float | None  # smallest sigma_min(J) seen on the fibre
    traced: bool  # r = 1: components come from tracing the fibre whole


@dataclass(frozen=True)
class ComponentSummary:
    """A component as the response describes it."""

    size: int
    representative_rad: FloatArray  # (n,) the member nearest the component's mean
    configurations_rad: FloatArray  # (k, n) all members, or a covering subset when capped
    joint_min_rad: FloatArray  # (n,)
    joint_max_rad: FloatArray  # (n,)
    max_position_error_m: float
    max_orientation_error_rad: float
    distance_to_reference_rad: float | None
    nearest_to_reference_rad: FloatArray | None  # (n,)
    arc_length_rad: float | None  # r = 1: the component's length along the fibre
    closed: bool | None  # r = 1: a whole loop inside the limits
    ends: tuple[EndReason, EndReason] | None  # r = 1, open: why its first and last points end
    path: ComponentPath | None  # r = 1, when the query asked for paths
    roadmap: ComponentRoadmap | None  # roadmap components, when the query asked for roadmaps
    clearance_m: float | None  # least distance to the robot itself and the obstacles along it
    safest_rad: FloatArray | None  # (n,) its configuration of greatest clearance
    safest_clearance_m: float | None  # that configuration's clearance


# -- out: the result ---------------------------------------------------------------------------


@dataclass(frozen=True)
class SampleCounts:
    """Where every sample went: sampled = accepted + rejected_tolerance +
    rejected_joint_limits + rejected_collision."""

    sampled: int
    accepted: int
    rejected_tolerance: int  # not within tolerance after correction (or not finite)
    rejected_joint_limits: int  # within tolerance but outside the joint limits
    rejected_collision: int  # within tolerance and the limits, but in collision

    @classmethod
    def of(cls, acceptance: Acceptance) -> SampleCounts:
        tolerance = acceptance.within_tolerance
        return cls(
            sampled=len(tolerance),
            accepted=int(acceptance.accepted.sum()),
            rejected_tolerance=int((~tolerance).sum()),
            rejected_joint_limits=int((tolerance & ~acceptance.within_limits).sum()),
            rejected_collision=int((acceptance.on_fibre & ~acceptance.collision_free).sum()),
        )


@dataclass(frozen=True)
class StageTimings:
    """Wall time of each stage, in `STAGES` order, and of the whole run, in ms."""

    stage_ms: dict[Stage, float]
    total_ms: float

    def as_dict(self) -> dict[TimedSpan, float]:
        """{"encode": ..., ..., "summarise": ..., "total": ...} in ms, keys as `TIMED_SPANS`."""
        spans: dict[TimedSpan, float] = {stage: self.stage_ms[stage] for stage in STAGES}
        spans["total"] = self.total_ms
        return spans


@dataclass(frozen=True)
class SmmResult:
    """The answer to one Query: every sample accounted for, the components in order."""

    counts: SampleCounts
    components: list[ComponentSummary]  # by distance to the reference when given, else size
    structure: FibreStructure
    timings: StageTimings
