"""POST /smm/batch: the self-motion manifolds of many targets of one model, in one request.

A planner asks for the SMMs along a path. Each target's answer is exactly POST /smm's for
the body `SmmBatchRequest.request_for(index)` (same checks, same seed, same answer); the
batch validates every target before it takes a computation slot, reports every bad
target in one 422, and holds one slot for the whole computation (`pipeline/batch.py`).
"""

from __future__ import annotations

from fastapi import APIRouter, Request, Response

from service.api.answers import Fields, encode, model_fields
from service.api.deps import AdmissionDep, MetricsDep, RegistryDep, SettingsDep
from service.api.schemas import error_responses
from service.api.smm import compute_in_slot, query_for_model, smm_fields
from service.config import Settings
from service.errors import (
    LimitExceededError,
    RequestFieldError,
    RequestFieldErrors,
)
from service.http.openapi import operation_id
from service.models.registry import ServedModel
from service.pipeline.batch import BatchResult, run_batch
from service.pipeline.deadline import Deadline
from service.pipeline.types import STAGES, Query, TimedSpan
from service.wire import SmmBatchRequest, SmmBatchResponse

router = APIRouter(prefix="/smm", tags=["smm"], generate_unique_id_function=operation_id)


def _at_target(error: RequestFieldError, body: SmmBatchRequest, index: int) -> RequestFieldError:
    """The error of target `index`'s POST /smm body, located in the batch: at
    `targets[index]` when the field is the target's own, else at the batch's field."""
    field = error.location[1]
    if field != "target" and getattr(body.targets[index], str(field), None) is None:
        return error  # an option the target took from the batch, or the batch's scene
    return RequestFieldError(
        ("body", "targets", index, *error.location[1:]), f"targets[{index}].{error.message}"
    )


def to_queries(body: SmmBatchRequest, model: ServedModel, settings: Settings) -> list[Query]:
    """Every target's Query, with the checks POST /smm makes, all before the batch waits
    for or takes a slot: shapes first (one 422 listing every bad target, each error once),
    then the server's limits on the work asked for (413)."""
    queries: list[Query] = []
    errors: dict[tuple[tuple[str | int, ...], str], RequestFieldError] = {}
    for index in range(len(body.targets)):
        try:
            queries.append(query_for_model(body.request_for(index), model))
        except RequestFieldError as error:
            located = _at_target(error, body, index)
            errors.setdefault((located.location, located.message), located)
    if errors:
        raise RequestFieldErrors(list(errors.values()))
    if len(queries) > settings.max_batch_targets:
        raise LimitExceededError(
            f"targets must hold at most {settings.max_batch_targets} targets on this server "
            f"(SMM_MAX_BATCH_TARGETS), got {len(queries)}"
        )
    for index, query in enumerate(queries):
        if query.num_samples > settings.max_num_samples:
            own = body.targets[index].num_samples is not None
            field = f"targets[{index}].num_samples" if own else "num_samples"
            raise LimitExceededError(
                f"{field} must be at most {settings.max_num_samples} on this server, got "
                f"{query.num_samples}"
            )
    total = sum(query.num_samples for query in queries)
    if total > settings.max_batch_samples:
        raise LimitExceededError(
            f"the targets' num_samples must add up to at most {settings.max_batch_samples} on "
            f"this server (SMM_MAX_BATCH_SAMPLES), got {total}"
        )
    return queries


def batch_fields(model: ServedModel, queries: list[Query], batch: BatchResult) -> Fields:
    """The batch's answer as `SmmBatchResponse`, field for field (service/api/answers.py):
    each answered target's `smm_fields`, the rest marked deadline_exceeded."""
    results: list[Fields] = []
    for index, query in enumerate(queries):
        if index < len(batch.results):
            answer = smm_fields(model, query, batch.results[index])
            results.append({"index": index, "status": answer["status"], "answer": answer})
        else:
            results.append({"index": index, "status": "deadline_exceeded", "answer": None})
    timings: dict[TimedSpan, float] = {
        stage: sum(r.timings.stage_ms.get(stage, 0.0) for r in batch.results) for stage in STAGES
    }
    timings["total"] = batch.total_ms
    return {
        **model_fields(model),
        "status": "complete" if batch.complete else "partial",
        "results": results,
        "timings_ms": timings,
    }


def answer_batch(
    model: ServedModel, queries: list[Query], deadline: Deadline, threads: int
) -> tuple[bytes, BatchResult]:
    """Run the batch on `threads` threads and encode its JSON answer (in a worker thread:
    both are CPU work). A batch stopped by the deadline before its first answer is a 504,
    as POST /smm's."""
    batch = run_batch(model, queries, deadline, threads)
    if batch.deadline_error is not None and not batch.results:
        raise batch.deadline_error
    return encode(batch_fields(model, queries, batch)), batch


@router.post(
    "/batch",
    response_model=SmmBatchResponse,
    responses=error_responses(
        400,
        401,
        404,
        413,
        415,
        503,
        504,
        meanings={
            413: "Body over SMM_MAX_BODY_BYTES, more targets than SMM_MAX_BATCH_TARGETS, a "
            "target's num_samples over SMM_MAX_NUM_SAMPLES, or their sum over "
            "SMM_MAX_BATCH_SAMPLES.",
            504: "The request ran past SMM_REQUEST_DEADLINE_S before its first target was "
            "answered (past it later, the answer is a 200 with status partial).",
        },
    ),
)
async def post_smm_batch(
    body: SmmBatchRequest,
    request: Request,
    registry: RegistryDep,
    settings: SettingsDep,
    admission: AdmissionDep,
    metrics: MetricsDep,
) -> Response:
    deadline = Deadline.after(settings.request_deadline_s)
    model = registry.get(body.robot, body.task)
    request.state.model = model.manifest.model_id  # the metrics' and access log's model label
    queries = to_queries(body, model, settings)
    content, batch = await compute_in_slot(
        admission, metrics, deadline, answer_batch, model, queries, deadline,
        settings.batch_threads_per_request,
    )  # fmt: skip
    for result in batch.results:
        metrics.observe_pipeline(model.manifest.model_id, result.timings, result.counts)
    return Response(content=content, media_type="application/json")
