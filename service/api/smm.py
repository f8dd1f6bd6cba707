"""POST /smm: the self-motion manifolds of one target."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

from fastapi import APIRouter, Request, Response
from starlette.concurrency import run_in_threadpool

from service.api.answers import (
    Fields,
    component_fields,
    counts_fields,
    encode,
    model_fields,
    structure_fields,
)
from service.api.deps import AdmissionDep, MetricsDep, RegistryDep, SettingsDep
from service.api.schemas import error_responses
from service.errors import (
    DeadlineExceededError,
    LimitExceededError,
    OverloadedError,
    RequestFieldError,
)
from service.http.admission import Admission
from service.http.openapi import operation_id
from service.models.registry import ServedModel
from service.observability.metrics import Metrics
from service.pipeline.collision.scene import Obstacle
from service.pipeline.deadline import Deadline
from service.pipeline.run import collision_of, run
from service.pipeline.types import Query, SmmResult
from service.wire import ObstacleIn, SmmRequest, SmmResponse

Computed = TypeVar("Computed")

router = APIRouter(prefix="/smm", tags=["smm"], generate_unique_id_function=operation_id)


def to_query(body: SmmRequest, model: ServedModel, max_num_samples: int) -> Query:
    """Fill the model's defaults into the request and check what depends on the model.

    Every check runs here, before the request waits for or takes a computation slot:
    the shape checks first (422), then the server's limit on the work asked for (413).
    """
    query = query_for_model(body, model)
    if query.num_samples > max_num_samples:
        raise LimitExceededError(
            f"num_samples must be at most {max_num_samples} on this server, got {query.num_samples}"
        )
    return query


def query_for_model(body: SmmRequest, model: ServedModel) -> Query:
    """The request as the model's Query, defaults filled in; RequestFieldError (422) for a
    shape the model refuses (obstacles included: a model without collision geometry
    cannot check them)."""
    if body.obstacles and model.robot_spheres is None:
        raise RequestFieldError(
            ("body", "obstacles"),
            f"obstacles cannot be checked on model {model.manifest.model_id}: it has no "
            "collision geometry (its URDF has no <collision> elements); send none, or use a "
            "model whose GET /robots entry has collision_geometry true",
        )
    orientation = body.target.orientation
    return Query.for_model(
        model.manifest,
        position_m=body.target.position,
        orientation_wxyz=None if orientation is None else orientation.wxyz(),
        axis=None if body.target.axis is None else tuple(body.target.axis),  # type: ignore[arg-type]
        num_samples=body.num_samples,
        seed=body.seed,
        tolerance_position_m=body.tolerance.position,
        tolerance_orientation_rad=body.tolerance.orientation,
        reference_rad=body.reference_configuration,
        max_configurations_per_component=body.max_configurations_per_component,
        include_paths=body.include_paths,
        include_roadmap=body.include_roadmap,
        obstacles=[_obstacle(i, o) for i, o in enumerate(body.obstacles)],
        check_self=body.collision.check_self,
        margin_m=body.collision.margin_m,
    )


def _obstacle(index: int, obstacle: ObstacleIn) -> Obstacle:
    """One obstacle of the request, checked (422 naming obstacles[index]'s field)."""
    orientation = obstacle.orientation
    return Obstacle.of(
        index,
        obstacle.shape,
        obstacle.dimensions,
        obstacle.position,
        None if orientation is None else orientation.wxyz(),
    )


def smm_fields(model: ServedModel, query: Query, result: SmmResult) -> Fields:
    """The answer as `SmmResponse`, field for field (service/api/answers.py)."""
    return {
        **model_fields(model),
        "status": "ok" if result.components else "no_solution",
        "counts": counts_fields(result.counts),
        "components": [component_fields(i, s) for i, s in enumerate(result.components)],
        "structure": structure_fields(result.structure),
        "collision": _collision_fields(model, query),
        "timings_ms": result.timings.as_dict(),
    }


def _collision_fields(model: ServedModel, query: Query) -> Fields:
    check = collision_of(model, query)
    return {
        "self_checked": check.self_checked,
        "obstacles": len(query.scene.obstacles),
        "margin_m": query.margin_m,
    }


def answer(model: ServedModel, query: Query, deadline: Deadline) -> tuple[bytes, SmmResult]:
    """Run the pipeline and encode the JSON answer (in a worker thread: both are CPU work)."""
    result = run(model, query, deadline)
    return encode(smm_fields(model, query, result)), result


async def compute_in_slot(
    admission: Admission,
    metrics: Metrics,
    deadline: Deadline,
    work: Callable[..., Computed],
    *args: object,
) -> Computed:
    """Wait for a computation slot (503 when the queue is full or the wait outlasts
    `deadline`), then run `work(*args)` in a worker thread, so the event loop keeps
    answering (probes, metrics, prompt 503s) while slots are busy; the wait is observed and
    a rejection counted by its reason."""
    arrived_s = time.perf_counter()
    try:
        async with admission.slot(deadline.remaining_s()):
            metrics.queue_wait.observe(time.perf_counter() - arrived_s)
            return await run_in_threadpool(work, *args)
    except OverloadedError as error:
        metrics.rejected.labels(error.reason).inc()
        raise
    except DeadlineExceededError:
        metrics.rejected.labels("deadline").inc()
        raise


@router.post(
    "",
    response_model=SmmResponse,
    responses=error_responses(400, 401, 404, 413, 415, 503, 504),
)
async def post_smm(
    body: SmmRequest,
    request: Request,
    registry: RegistryDep,
    settings: SettingsDep,
    admission: AdmissionDep,
    metrics: MetricsDep,
) -> Response:
    deadline = Deadline.after(settings.request_deadline_s)
    model = registry.get(body.robot, body.task)
    request.state.model = model.manifest.model_id  # the metrics' and access log's model label
    query = to_query(body, model, settings.max_num_samples)
    content, result = await compute_in_slot(
        admission, metrics, deadline, answer, model, query, deadline
    )
    metrics.observe_pipeline(model.manifest.model_id, result.timings, result.counts)
    return Response(content=content, media_type="application/json")
