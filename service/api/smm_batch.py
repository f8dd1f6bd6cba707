"""POST /smm/batch: the self-motion manifolds of many targets of one model, in one request.

A planner asks for the SMMs along a path. Each target's answer is exactly POST /smm's for
the body `SmmBatchRequest.request_for(index)` (same checks, same seed, same answer); the
batch validates every target before it takes a computation slot, reports every bad
target in one 422, and holds one slot for the whole computation (`pipeline/batch.py`).
With `Accept: application/x-ndjson` the same answer comes as lines, each target's sent
as soon as it is answered (`batch_lines.py`).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.responses import StreamingResponse

from service.api.answers import Fields, encode, model_fields
from service.api.batch_lines import (
    BatchLines,
    ClientGone,
    first_line_or_error,
    wants_lines,
)
from service.api.deps import AdmissionDep, MetricsDep, RegistryDep, SettingsDep
from service.api.schemas import error_responses
from service.api.smm import compute_in_slot, query_for_model, smm_fields
from service.config import Settings
from service.errors import (
    LimitExceededError,
    RequestFieldError,
    RequestFieldErrors,
)
from service.http.admission import Admission
from service.http.openapi import operation_id
from service.models.registry import ServedModel
from service.observability.metrics import Metrics
from service.pipeline.batch import BatchResult, run_batch
from service.pipeline.deadline import Deadline
from service.pipeline.types import STAGES, Query, SmmResult, TimedSpan
from service.wire import BATCH_LINES, NDJSON, SmmBatchRequest, SmmBatchResponse

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


def item_fields(model: ServedModel, query: Query, index: int, result: SmmResult | None) -> Fields:
    """Target `index`'s entry of the batch's results, as `BatchItemOut`: its `smm_fields`,
    or deadline_exceeded when it was not answered (`result` None)."""
    if result is None:
        return {"index": index, "status": "deadline_exceeded", "answer": None}
    answer = smm_fields(model, query, result)
    return {"index": index, "status": answer["status"], "answer": answer}


def end_fields(batch: BatchResult) -> Fields:
    """How the batch ended, as `SmmBatchEnd`: its status and timings."""
    timings: dict[TimedSpan, float] = {
        stage: sum(r.timings.stage_ms.get(stage, 0.0) for r in batch.results) for stage in STAGES
    }
    timings["total"] = batch.total_ms
    return {"status": "complete" if batch.complete else "partial", "timings_ms": timings}


def batch_fields(model: ServedModel, queries: list[Query], batch: BatchResult) -> Fields:
    """The batch's answer as `SmmBatchResponse`, field for field (service/api/answers.py):
    the head, each target's `item_fields`, the end: what the NDJSON lines carry."""
    answered = [*batch.results, *[None] * (len(queries) - len(batch.results))]
    results = [
        item_fields(model, query, index, result)
        for index, (query, result) in enumerate(zip(queries, answered, strict=True))
    ]
    end = end_fields(batch)
    return {**model_fields(model), "status": end["status"], "results": results, **end}


def observer(model: ServedModel, metrics: Metrics) -> Callable[[SmmResult], None]:
    """What a batch tells the metrics of each answer it computes: its stages and samples,
    as POST /smm's, whether or not the answer is sent (the work was done)."""
    model_id = model.manifest.model_id

    def observe(result: SmmResult) -> None:
        metrics.observe_pipeline(model_id, result.timings, result.counts)

    return observe


def answer_batch(
    model: ServedModel, queries: list[Query], deadline: Deadline, threads: int, metrics: Metrics
) -> bytes:
    """Run the batch on `threads` threads and encode its JSON answer (in a worker thread:
    both are CPU work). A batch stopped by the deadline before its first answer is a 504,
    as POST /smm's."""
    batch = run_batch(model, queries, deadline, threads, on_computed=observer(model, metrics))
    if batch.deadline_error is not None and not batch.results:
        raise batch.deadline_error
    return encode(batch_fields(model, queries, batch))


def answer_lines(
    model: ServedModel,
    queries: list[Query],
    deadline: Deadline,
    threads: int,
    lines: BatchLines,
    metrics: Metrics,
) -> None:
    """In a worker thread, the batch as NDJSON lines: the head with the first answer, each
    target's `item_fields` as it is answered, those the deadline left unanswered, the
    `end_fields`. Stopped by the deadline before its first answer, it raises (a 504), as
    `answer_batch`; stopped by the client leaving, it returns."""

    def on_answer(index: int, result: SmmResult) -> None:
        if index == 0:
            lines.put(encode(model_fields(model)) + b"\n")
        lines.put(encode(item_fields(model, queries[index], index, result)) + b"\n")

    try:
        batch = run_batch(model, queries, deadline, threads, on_answer, observer(model, metrics))
        if batch.deadline_error is not None and not batch.results:
            raise batch.deadline_error
        for index in range(len(batch.results), len(queries)):
            lines.put(encode(item_fields(model, queries[index], index, None)) + b"\n")
        lines.put(encode(end_fields(batch)) + b"\n")
    except ClientGone:
        pass
    finally:
        lines.close()


_COMPUTING: set[asyncio.Future[None]] = set()  # the streamed batches' computations, held


def _computed(computation: asyncio.Future[None]) -> None:
    """A streamed batch's computation ended: let it go, its error marked as seen (the
    lines' reader raises it where a reader is left; where none is, nobody can be told)."""
    _COMPUTING.discard(computation)
    if not computation.cancelled():
        computation.exception()


async def stream_batch(
    model: ServedModel,
    queries: list[Query],
    settings: Settings,
    deadline: Deadline,
    admission: Admission,
    metrics: Metrics,
) -> StreamingResponse:
    """The batch as NDJSON lines (batch_lines.py), computed in its slot; returned once the
    first target is answered, so a 503 or 504 is still the response's status."""
    lines = BatchLines()
    threads = settings.batch_threads_per_request
    computing = compute_in_slot(
        admission, metrics, deadline, answer_lines, model, queries, deadline, threads, lines,
        metrics,
    )  # fmt: skip
    computation = asyncio.ensure_future(computing)
    _COMPUTING.add(computation)
    computation.add_done_callback(_computed)
    await first_line_or_error(lines, computation)
    return StreamingResponse(lines.read(computation), media_type=NDJSON)


LINES_RESPONSE: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "The batch's answer: one JSON object, or with `Accept: "
        "application/x-ndjson` the same answer as lines, each sent once its target is answered "
        "(the SmmBatchHead, one BatchItemOut per target in order, the SmmBatchEnd; a stream "
        "without the SmmBatchEnd was cut off).",
        "content": {
            NDJSON: {
                "schema": {
                    "description": "Each line is one JSON object: the first a SmmBatchHead, "
                    "then a BatchItemOut per target in order, the last a SmmBatchEnd.",
                    "oneOf": [
                        {"$ref": f"#/components/schemas/{line.__name__}"} for line in BATCH_LINES
                    ],
                }
            }
        },
    }
}


@router.post(
    "/batch",
    response_model=SmmBatchResponse,
    responses=LINES_RESPONSE
    | error_responses(
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
    if wants_lines(request):
        return await stream_batch(model, queries, settings, deadline, admission, metrics)
    content = await compute_in_slot(
        admission, metrics, deadline, answer_batch, model, queries, deadline,
        settings.batch_threads_per_request, metrics,
    )  # fmt: skip
    return Response(content=content, media_type="application/json")
