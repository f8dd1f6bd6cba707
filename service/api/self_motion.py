"""POST /smm/self-motion: a path along the self-motion manifold from a start to a goal.

The planner's question: "I am at q; take me along the self-motion to q' (or to the
configuration of this component farthest from the limits, nearest a configuration, or of
greatest clearance)". The body is POST /smm's target and options with a `start` and a
`goal`; the answer is `service.pipeline.self_motion`'s, computed in a slot as POST /smm's.
"""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, Request, Response

from service.api.answers import (
    Fields,
    component_fields,
    counts_fields,
    encode,
    floats_or_none,
    model_fields,
    roadmap_fields,
)
from service.api.deps import AdmissionDep, MetricsDep, RegistryDep, SettingsDep
from service.api.schemas import error_responses
from service.api.smm import compute_in_slot, to_query
from service.errors import RequestFieldError
from service.http.openapi import operation_id
from service.models.registry import ServedModel
from service.pipeline.deadline import Deadline
from service.pipeline.run import collision_of
from service.pipeline.self_motion import OBJECTIVES, Goal, SelfMotion, self_motion
from service.pipeline.types import Query
from service.wire import GoalIn, SelfMotionRequest, SelfMotionResponse, SmmRequest

router = APIRouter(prefix="/smm", tags=["smm"], generate_unique_id_function=operation_id)

# The fields of a POST /smm body that a self-motion body shares.
SHARED = ("robot", "task", "target", "num_samples", "seed", "tolerance", "obstacles", "collision")


def goal_of(goal: GoalIn, joints: int) -> Goal:
    """The goal as the pipeline takes it; RequestFieldError unless exactly one field is given
    and a configuration has one value per joint."""
    given = [name for name in ("configuration", "objective", "nearest_to") if getattr(goal, name)]
    if len(given) != 1:
        raise RequestFieldError(
            ("body", "goal"),
            "goal takes exactly one of configuration, objective (max_limit_margin or "
            f"max_clearance) and nearest_to; got {given or 'none'}",
        )
    for name in ("configuration", "nearest_to"):
        value = getattr(goal, name)
        if value is not None and len(value) != joints:
            raise RequestFieldError(
                ("body", "goal", name),
                f"goal.{name} must have {joints} values (one per joint), got {len(value)}",
            )
    if goal.configuration is not None:
        return Goal(configuration_rad=np.asarray(goal.configuration, dtype=np.float64))
    if goal.nearest_to is not None:
        return Goal(objective="nearest_to", nearest_to_rad=np.asarray(goal.nearest_to))
    return Goal(objective=goal.objective)


def to_self_motion(
    body: SelfMotionRequest, model: ServedModel, max_num_samples: int
) -> tuple[Query, np.ndarray, Goal]:
    """The query, start and goal, every shape checked before a slot is taken."""
    joints = model.manifest.joints.count
    if len(body.start) != joints:
        raise RequestFieldError(
            ("body", "start"),
            f"start must have {joints} values (one per joint), got {len(body.start)}",
        )
    goal = goal_of(body.goal, joints)
    if goal.objective == "max_limit_margin" and model.limits.periodic.all():
        raise RequestFieldError(
            ("body", "goal", "objective"),
            f"model {model.manifest.model_id} has no joint limits, so max_limit_margin is the "
            "same everywhere; give a configuration or nearest_to, or max_clearance",
        )
    request = SmmRequest.model_validate(body.model_dump(include=set(SHARED), by_alias=True))
    query = to_query(request, model, max_num_samples)
    if goal.objective == "max_clearance" and not collision_of(model, query).active:
        raise RequestFieldError(
            ("body", "goal", "objective"),
            "max_clearance needs collisions checked: give obstacles or collision.self on a "
            f"model with collision geometry; or choose from {list(OBJECTIVES[:2])}",
        )
    return query, np.asarray(body.start, dtype=np.float64), goal


def answer(
    model: ServedModel, query: Query, start: np.ndarray, goal: Goal, deadline: Deadline
) -> tuple[bytes, SelfMotion]:
    """The self-motion and its JSON (in a worker thread: both are CPU work)."""
    motion = self_motion(model, query, start, goal, deadline)
    return encode(self_motion_fields(model, motion)), motion


def self_motion_fields(model: ServedModel, motion: SelfMotion) -> Fields:
    """The self-motion's answer as `SelfMotionResponse`, field for field
    (service/api/answers.py): each component lean (its representative, no path)."""
    result, path = motion.result, motion.path_rad
    roadmap = result.components[motion.start_component].roadmap
    return {
        **model_fields(model),
        "status": motion.status,
        "start_component": motion.start_component,
        "goal_component": motion.goal_component,
        "path": floats_or_none(path),
        "length_rad": motion.length_rad,
        "objective_value": motion.objective_value,
        "roadmap": None if roadmap is None else roadmap_fields(roadmap),
        "components": [component_fields(i, s, lean=True) for i, s in enumerate(result.components)],
        "counts": counts_fields(result.counts),
        "timings_ms": result.timings.as_dict(),
    }


@router.post(
    "/self-motion",
    response_model=SelfMotionResponse,
    responses=error_responses(400, 401, 404, 413, 415, 503, 504),
)
async def post_self_motion(
    body: SelfMotionRequest,
    request: Request,
    registry: RegistryDep,
    settings: SettingsDep,
    admission: AdmissionDep,
    metrics: MetricsDep,
) -> Response:
    deadline = Deadline.after(settings.request_deadline_s)
    model = registry.get(body.robot, body.task)
    request.state.model = model.manifest.model_id
    query, start, goal = to_self_motion(body, model, settings.max_num_samples)
    content, motion = await compute_in_slot(
        admission, metrics, deadline, answer, model, query, start, goal, deadline
    )
    metrics.observe_pipeline(model.manifest.model_id, motion.result.timings, motion.result.counts)
    return Response(content=content, media_type="application/json")
