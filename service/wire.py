"""The HTTP contract's request and response models: the wire format, in one place.

Shared by the server (`service.api` answers with them; the OpenAPI document is generated
from them) and by the Python client (`service.client` sends and parses them), so the two
cannot drift. Only pydantic here: the client imports this module without numpy, fastapi
or onnxruntime (a test checks).

Names follow one rule: a whole body ends in `Request` or `Response`, a part of one in `In`
(inside a request) or `Out` (inside a response), so no wire model shares a name with the
pipeline's types (`Target`, `SampleCounts`, ...).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

# What `timings_ms` times: every pipeline stage in run order, and the whole run. Spelt out
# here because the pipeline's `TimedSpan` (service/pipeline/types.py) lives with numpy; a
# test checks the two are the same names in the same order.
TimedSpan = Literal["encode", "sample", "correct", "accept", "connect", "summarise", "total"]

# JSON has no NaN or infinity; refuse them where a parser lets them through.
Finite = Annotated[float, Field(allow_inf_nan=False)]
# The options of a query, constrained once: POST /smm and each target of POST /smm/batch.
NumSamples = Annotated[int, Field(ge=1)]
Seed = Annotated[int, Field(ge=0, le=2**63 - 1)]
MaxConfigurations = Annotated[int, Field(ge=1)]
# Obstacles one request may carry: a planning scene's worth of primitives. Each costs a
# distance kernel over the robot's moving spheres at every checked configuration.
MAX_OBSTACLES = 64
# The largest margin a request may ask for, in metres: beyond it nothing near the robot
# is free anyway.
MAX_MARGIN_M = 0.5
ShapeName = Literal["box", "sphere", "cylinder", "capsule"]
# A configuration in an answer: joint values in radians, in the robot's joint order. A tuple,
# not a list: CPython's cyclic garbage collector stops tracking a tuple of floats once it
# has seen it, so a client holding many answers does not rescan their thousands of path
# points at every collection (`python -m tools.client_parse` measures the parse both ways).
ConfigurationOut = tuple[float, ...]

# A configuration in a request: joint values in radians, as a list or a tuple (one taken
# from an answer); strict like the rest of a request, so a string is not one.
ConfigurationIn = Sequence[Finite]


class _Request(BaseModel):
    # A misspelt option must not silently fall back to its default, and a string or a
    # boolean is not a number (strict: no "0.5" -> 0.5 or true -> 1.0 coercion).
    model_config = ConfigDict(extra="forbid", strict=True)


class QuaternionIn(_Request):
    """Unit quaternion w + xi + yj + zk, fields named so the order is never ambiguous."""

    w: Finite
    x: Finite
    y: Finite
    z: Finite

    def wxyz(self) -> tuple[float, float, float, float]:
        return (self.w, self.x, self.y, self.z)


class TargetIn(_Request):
    position: list[Finite] = Field(
        min_length=1,
        max_length=3,
        description="End-effector position in metres, base frame; one value per constrained "
        "axis (2 for a planar arm, 3 in space).",
        examples=[[0.5, 0.0]],
    )
    orientation: QuaternionIn | None = Field(
        None, description="Required for the pose task, refused for the others."
    )
    axis: list[Finite] | None = Field(
        None,
        min_length=3,
        max_length=3,
        description="Axis task only (required there, refused for the others): the direction, "
        "base frame, unit, that the tool axis points along; the rotation about it is free.",
        examples=[[0.0, 0.0, -1.0]],
    )


class ToleranceIn(_Request):
    position: Annotated[float, Field(gt=0.0, le=0.1, allow_inf_nan=False)] | None = Field(
        None, description="Largest accepted position error in metres (default: the model's)."
    )
    orientation: Annotated[float, Field(gt=0.0, le=3.14, allow_inf_nan=False)] | None = Field(
        None,
        description="Largest accepted orientation error in radians: the rotation angle for the "
        "pose task, the angle between the tool axis and target.axis for the axis task "
        "(refused for the position task; default: the model's).",
    )


class ObstacleIn(_Request):
    """A solid primitive of the planning scene (MoveIt's shape_msgs/SolidPrimitive), in the
    model's base frame."""

    shape: ShapeName
    dimensions: list[Finite] = Field(
        min_length=1,
        max_length=3,
        description="Metres. box: [x, y, z] full side lengths; sphere: [radius]; cylinder: "
        "[height, radius] along its z axis; capsule: [height, radius], height the distance "
        "between the two cap centres along z (total length height + 2 radius). Each "
        "shape is centred on its position.",
        examples=[[0.8, 1.2, 0.05]],
    )
    position: list[Finite] = Field(
        min_length=3,
        max_length=3,
        description="Centre in metres, base frame.",
        examples=[[0.5, 0, -0.03]],
    )
    orientation: QuaternionIn | None = Field(
        None,
        description="Unit quaternion of the shape's frame in the base frame; identity "
        "when left out (and meaningless for a sphere).",
    )


class CollisionIn(_Request):
    # "self" on the wire (a Python keyword's neighbour as a field name): read and written
    # by that name, so the client sends what the server reads.
    model_config = ConfigDict(
        extra="forbid", strict=True, validate_by_name=True, serialize_by_alias=True
    )

    check_self: bool = Field(
        True,
        alias="self",
        description="Check the robot against itself (on models whose URDF has collision "
        "geometry; the answer's collision.self_checked says whether it was).",
    )
    margin_m: Annotated[float, Field(ge=0.0, le=MAX_MARGIN_M, allow_inf_nan=False)] = Field(
        0.0,
        description="Least clearance, in metres, a returned configuration keeps from the "
        "obstacles and between the robot's own bodies.",
    )


class SmmRequest(_Request):
    robot: str = Field(examples=["planar3r"])
    task: str = Field(examples=["position"])
    target: TargetIn
    num_samples: NumSamples | None = Field(
        None,
        description="Flow samples to draw, at most (default: the model's; 413 above the "
        "limit). A model that draws in rounds stops after a round that finds no new curve "
        "(counts.sampled says how many it drew).",
    )
    seed: Seed = Field(0, description="The same seed gives the same answer.")
    tolerance: ToleranceIn = Field(default_factory=ToleranceIn)
    reference_configuration: ConfigurationIn | None = Field(
        None,
        description="Joint angles in radians (model joint order); components are then ordered "
        "by their distance to it and report their nearest member.",
    )
    max_configurations_per_component: MaxConfigurations | None = Field(
        None,
        description="Cap on configurations returned per component (a covering subset by "
        "farthest-point sampling); `size` still counts every member. Default: all.",
    )
    include_paths: bool = Field(
        True,
        description="For a 1-D self-motion (redundancy 1), return each component's ordered "
        "`path`; false keeps answers small (`arc_length_rad` and `closed` stay).",
    )
    include_roadmap: bool = Field(
        False,
        description="Return the roadmap of each component a roadmap decided (redundancy "
        "above 1, and at redundancy 1 samples on no traced curve): its nodes and the edges "
        "joining them, a graph a planner can move along.",
    )
    obstacles: list[ObstacleIn] = Field(
        default_factory=list,
        max_length=MAX_OBSTACLES,
        description=f"The planning scene (at most {MAX_OBSTACLES}): every returned "
        "configuration and path point is clear of each by at least collision.margin_m.",
    )
    collision: CollisionIn = Field(default_factory=lambda: CollisionIn.model_validate({}))


class CountsOut(BaseModel):
    """Where every sample went: sampled = accepted + rejected_tolerance +
    rejected_joint_limits + rejected_collision."""

    sampled: int
    accepted: int
    rejected_tolerance: int
    rejected_joint_limits: int
    rejected_collision: int = Field(
        description="Within tolerance and the limits, but in collision (with the margin)."
    )


class RoadmapOut(BaseModel):
    """How to move within a component of redundancy above 1."""

    nodes: list[ConfigurationOut] = Field(
        description="Configurations: the component's members first, in the order of "
        "`configurations` when that is not capped, then the nodes the connect stage added "
        "to join them. Every node is within tolerance, inside the limits and free of "
        "collision (when checked)."
    )
    edges: list[list[int]] = Field(
        description="Pairs [i, j] (i < j) of node indices joined by a motion checked on the "
        "self-motion manifold: every step of it projected onto the fibre (within the "
        "connectivity's projection tolerance, 1e-4), inside the limits and free of "
        "collision. Any two nodes are joined by a path of edges."
    )


class ComponentOut(BaseModel):
    id: int
    size: int = Field(description="Accepted configurations in this component.")
    representative: ConfigurationOut
    configurations: list[ConfigurationOut]
    joint_min: ConfigurationOut
    joint_max: ConfigurationOut
    max_position_error: float = Field(description="metres")
    max_orientation_error: float = Field(description="radians; 0 for a position task")
    distance_to_reference: float | None = Field(description="joint metric, radians")
    nearest_to_reference: ConfigurationOut | None
    arc_length_rad: float | None = Field(
        description="Redundancy 1: the component's length along the fibre (joint metric); "
        "null otherwise."
    )
    closed: bool | None = Field(
        description="Redundancy 1: true when the component is a whole loop inside the limits "
        "(the path's last point joins its first); false when its ends are at joint limits."
    )
    ends: list[Literal["joint_limit", "collision"]] | None = Field(
        description="Redundancy 1, an open component: why its first and its last path "
        "point end it, at a joint limit or where the curve enters collision. Null for a "
        "closed loop and for redundancy above 1."
    )
    path: list[ConfigurationOut] | None = Field(
        description="Redundancy 1: the whole component, configurations in order along the "
        "curve, consecutive ones at most 0.05 rad apart, every one within tolerance, inside "
        "the limits and free of collision. Null for redundancy above 1 or when "
        "include_paths is false."
    )
    roadmap: RoadmapOut | None = Field(
        None,
        description="With include_roadmap: the component's roadmap, where a roadmap decided "
        "it. Null otherwise (a traced 1-D component has its `path`).",
    )
    clearance_m: float | None = Field(
        description="The least distance, in metres, from the robot to the obstacles and to "
        "itself over the component's configurations and path points (a lower bound of the "
        "true distance: measured on spheres that cover the robot's collision geometry). "
        "Null when nothing was checked."
    )
    safest_configuration: ConfigurationOut | None = Field(
        description="The component's configuration (member or path point) of greatest "
        "clearance. Null when nothing was checked."
    )
    safest_clearance_m: float | None = Field(
        description="That configuration's clearance, in metres. Null when nothing was checked."
    )


class StructureOut(BaseModel):
    near_singular: bool = Field(
        description="The target is near a singular value of the kinematics (the Jacobian "
        "nearly loses rank on the fibre, a curve could not be traced through, or two "
        "strands of the fibre run closer than the tracing resolves): components may touch "
        "there, so their number may be ambiguous. Every returned configuration is still "
        "exact and inside the limits."
    )
    min_singular_value: float | None = Field(
        description="Smallest singular value of the task Jacobian seen on the fibre."
    )
    traced: bool = Field(
        description="Components were decided by tracing the fibre whole (redundancy 1); "
        "otherwise by a roadmap whose edges were checked on the fibre."
    )


class CollisionOut(BaseModel):
    self_checked: bool = Field(
        description="Self-collision was checked: asked for, and the model has collision "
        "geometry (false: the model's URDF has none, or collision.self was false)."
    )
    obstacles: int = Field(description="Obstacles every answer is clear of.")
    margin_m: float


class SmmResponse(BaseModel):
    robot: str
    task: str
    model: str = Field(description="<model-id>@<first 12 hex of the model files' digest>")
    joint_names: list[str]
    redundancy: int
    status: Literal["ok", "no_solution"]
    counts: CountsOut
    components: list[ComponentOut]
    structure: StructureOut
    collision: CollisionOut
    timings_ms: dict[TimedSpan, float] = Field(
        description="Wall time in ms of each pipeline stage, in order, and of the whole run."
    )


class GoalIn(_Request):
    """Where a self-motion goes: exactly one of the fields."""

    configuration: ConfigurationIn | None = Field(
        None,
        description="Joint angles in radians (model joint order): a configuration of the "
        "start's component, brought onto the fibre as the start is.",
    )
    objective: Literal["max_limit_margin", "max_clearance"] | None = Field(
        None,
        description="max_limit_margin: the configuration of the start's component farthest "
        "from the joint limits (the least over the joints of the distance to the nearer "
        "limit); max_clearance: of greatest clearance from the obstacles and the robot "
        "itself (collisions checked). Among the component's roadmap nodes (r > 1) or "
        "path points (r = 1).",
    )
    nearest_to: ConfigurationIn | None = Field(
        None,
        description="Joint angles in radians: the configuration of the start's component "
        "nearest them (joint metric), among its roadmap nodes or path points.",
    )


class SelfMotionRequest(_Request):
    """A self-motion: from `start` to `goal`, staying on the target's self-motion manifold."""

    robot: str = Field(examples=["iiwa14"])
    task: str = Field(examples=["position"])
    target: TargetIn
    start: ConfigurationIn = Field(
        description="Joint angles in radians (model joint order) where the motion starts: "
        "within 0.1 rad (joint metric) of a configuration that reaches the target, inside "
        "the limits and free of collision; brought onto it by Newton (422 otherwise)."
    )
    goal: GoalIn
    num_samples: NumSamples | None = Field(None, description="As in POST /smm.")
    seed: Seed = Field(0, description="As in POST /smm.")
    tolerance: ToleranceIn = Field(default_factory=ToleranceIn)
    obstacles: list[ObstacleIn] = Field(
        default_factory=list,
        max_length=MAX_OBSTACLES,
        description="As in POST /smm: every path point is clear of each.",
    )
    collision: CollisionIn = Field(default_factory=lambda: CollisionIn.model_validate({}))


class SelfMotionResponse(BaseModel):
    robot: str
    task: str
    model: str = Field(description="<model-id>@<first 12 hex of the model files' digest>")
    joint_names: list[str]
    redundancy: int
    status: Literal["ok", "not_connected", "no_path"] = Field(
        description="ok: `path` joins start and goal; not_connected: they lie on different "
        "components (`start_component`, `goal_component`), which no self-motion joins; "
        "no_path (r > 1): one component, but no motion at the path's spacing and tolerance "
        "was found along its roadmap (an edge the connect stage walked at its coarser step, "
        "next to a singular set)."
    )
    start_component: int = Field(description="Index into `components` of the start's.")
    goal_component: int = Field(description="Index into `components` of the goal's.")
    path: list[ConfigurationOut] | None = Field(
        description="ok: configurations from the start (brought onto the fibre) to the goal, "
        "consecutive ones at most 0.05 rad apart (joint metric), every one within "
        "tolerance, inside the limits and free of collision (where checked)."
    )
    length_rad: float | None = Field(description="The path's joint-metric length.")
    objective_value: float | None = Field(
        description="With an objective: its value at the goal (max_limit_margin: rad; "
        "nearest_to: the distance in rad; max_clearance: m)."
    )
    roadmap: RoadmapOut | None = Field(
        description="r > 1: the start component's roadmap, whose nodes the objective chose "
        "from and whose edges the path follows; null for r = 1 (the path follows the "
        "traced curve)."
    )
    components: list[ComponentOut] = Field(
        description="The components of the answer the path lies in, as POST /smm describes "
        "them (one configuration each, no paths or roadmaps)."
    )
    counts: CountsOut
    timings_ms: dict[TimedSpan, float]


class BatchTargetIn(_Request):
    """One target of a batch: the `target` of a POST /smm body, and any of that body's
    options to use for this target instead of the batch's."""

    target: TargetIn
    num_samples: NumSamples | None = Field(None, description="Default: the batch's.")
    seed: Seed | None = Field(None, description="Default: the batch's.")
    tolerance: ToleranceIn | None = Field(
        None, description="Default: the batch's (replaced whole, not field by field)."
    )
    reference_configuration: ConfigurationIn | None = Field(
        None,
        description="Default: the batch's; the previous waypoint's configuration, say, to "
        "order this target's components by their distance to it.",
    )
    max_configurations_per_component: MaxConfigurations | None = Field(
        None, description="Default: the batch's."
    )
    include_paths: bool | None = Field(None, description="Default: the batch's.")
    include_roadmap: bool | None = Field(None, description="Default: the batch's.")


# The options a batch target may give for itself, in SmmRequest's names.
BATCH_TARGET_OPTIONS = (
    "num_samples",
    "seed",
    "tolerance",
    "reference_configuration",
    "max_configurations_per_component",
    "include_paths",
    "include_roadmap",
)


class SmmBatchRequest(_Request):
    """Many targets of one model. Each target is answered as POST /smm answers the body
    `request_for(index)`: the batch's robot and task, the target, and every option the
    target gives (not null) or else the batch's."""

    robot: str = Field(examples=["planar3r"])
    task: str = Field(examples=["position"])
    targets: list[BatchTargetIn] = Field(
        min_length=1,
        description="The targets, answered in this order (413 above the server's "
        "SMM_MAX_BATCH_TARGETS, 64 by default).",
        examples=[[{"target": {"position": [0.5, 0.0]}}, {"target": {"position": [0.5, 0.1]}}]],
    )
    num_samples: NumSamples | None = Field(
        None,
        description="Flow samples per target (default: the model's; 413 above the limit per "
        "target, or above SMM_MAX_BATCH_SAMPLES over all the targets).",
    )
    seed: Seed = Field(0, description="The same seed gives the same answer.")
    tolerance: ToleranceIn = Field(default_factory=ToleranceIn)
    reference_configuration: ConfigurationIn | None = Field(
        None, description="As in POST /smm, for every target that gives none."
    )
    max_configurations_per_component: MaxConfigurations | None = Field(
        None, description="As in POST /smm."
    )
    include_paths: bool = Field(True, description="As in POST /smm.")
    include_roadmap: bool = Field(False, description="As in POST /smm.")
    obstacles: list[ObstacleIn] = Field(
        default_factory=list,
        max_length=MAX_OBSTACLES,
        description="As in POST /smm: one scene for every target.",
    )
    collision: CollisionIn = Field(
        default_factory=lambda: CollisionIn.model_validate({}),
        description="As in POST /smm, for every target.",
    )

    def request_for(self, index: int) -> SmmRequest:
        """The POST /smm body whose answer is this batch's answer for `targets[index]`."""
        item = self.targets[index]
        options = {}
        for name in BATCH_TARGET_OPTIONS:
            own = getattr(item, name)
            options[name] = getattr(self, name) if own is None else own
        return SmmRequest(
            robot=self.robot,
            task=self.task,
            target=item.target,
            obstacles=self.obstacles,
            collision=self.collision,
            **options,
        )


class BatchItemOut(BaseModel):
    index: int = Field(description="The target's position in the request's `targets`.")
    status: Literal["ok", "no_solution", "deadline_exceeded"] = Field(
        description="ok or no_solution: the answer's own status; deadline_exceeded: the "
        "request's deadline passed before this target was answered (no answer; send it again)."
    )
    answer: SmmResponse | None = Field(
        description="Exactly POST /smm's answer to this target with the same options and "
        "seed (timings aside: their total is the sum of its stages, which a batch does not "
        "run back to back)."
    )


# POST /smm/batch's answer as lines (SmmBatchResponse): asked for with `Accept`, sent so.
NDJSON = "application/x-ndjson"


class SmmBatchHead(BaseModel):
    """The model that answers a batch: SmmBatchResponse's first fields, and the first line
    of its NDJSON stream."""

    robot: str
    task: str
    model: str = Field(description="<model-id>@<first 12 hex of the model files' digest>")
    joint_names: list[str]
    redundancy: int


BatchStatus = Annotated[
    Literal["complete", "partial"],
    Field(
        description="complete: every target answered; partial: the request's deadline "
        "stopped the batch, and the targets from the first unanswered one on have status "
        "deadline_exceeded."
    ),
]
BatchTimings = Annotated[
    dict[TimedSpan, float],
    Field(
        description="Per stage, the sum over the answered targets, in ms; total: the wall "
        "time of the whole batch (less than the sum of the stages where sampling ran beside "
        "the other stages)."
    ),
]


class SmmBatchEnd(BaseModel):
    """How a batch ended: SmmBatchResponse's last fields, and the last line of its NDJSON
    stream (a stream without it was cut off)."""

    status: BatchStatus
    timings_ms: BatchTimings


class SmmBatchResponse(SmmBatchHead):
    """The whole batch as one JSON object. Asked with `Accept: application/x-ndjson`, the
    same answer comes as lines, each sent once its target is answered: the SmmBatchHead,
    then one BatchItemOut per target in order, then the SmmBatchEnd."""

    status: BatchStatus
    results: list[BatchItemOut] = Field(description="One per target, in the request's order.")
    timings_ms: BatchTimings

    @classmethod
    def of_lines(
        cls, head: SmmBatchHead, results: list[BatchItemOut], end: SmmBatchEnd
    ) -> SmmBatchResponse:
        """The answer a batch's NDJSON lines make up."""
        return cls(**dict(head), status=end.status, results=results, timings_ms=end.timings_ms)


# The models an NDJSON batch's lines are, in the order they come: one head, one item per
# target, one end.
BATCH_LINES: tuple[type[BaseModel], ...] = (SmmBatchHead, BatchItemOut, SmmBatchEnd)


class RobotOut(BaseModel):
    robot: str
    task: str
    model: str
    joint_names: list[str]
    joint_lower: list[float]
    joint_upper: list[float]
    periodic_joints: list[bool]
    redundancy: int
    target_position_length: int
    orientation: bool
    tool_axis: list[float] | None = Field(
        None,
        description="Axis task only: the tool axis, a unit vector in the end-effector frame, "
        "that target.axis sets the direction of (the rotation about it is free).",
    )
    collision_geometry: bool = Field(
        description="The model has collision geometry: its answers can be checked for "
        "self-collision and against a request's obstacles."
    )
    defaults: dict[str, object]
    training: dict[str, object]
    quality: dict[str, object] | None


class RobotsResponse(BaseModel):
    models: list[RobotOut]


class ErrorResponse(BaseModel):
    """Every error but a malformed body's (422) is `{"detail": "<what, and what is allowed>"}`."""

    detail: str


class LivenessResponse(BaseModel):
    status: Literal["alive"]


class FailedModelOut(BaseModel):
    name: str = Field(description="The model directory's name (the model id).")
    reason: str = Field(description="Why it failed verification, naming the file.")


class ReadinessResponse(BaseModel):
    status: Literal["ready", "not_ready", "loading", "draining"] = Field(
        description="ready: every model found was loaded and verified (200); otherwise 503."
    )
    models: list[str] = Field(description="Served models, `<model-id>@<version>`.")
    failed: list[FailedModelOut] = Field(
        description="Models that failed verification at start-up and are not served."
    )
