"""GET /metrics: the app's Prometheus metrics (open even when an API key is set)."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response

from service.api.deps import MetricsDep
from service.http.openapi import operation_id

router = APIRouter(tags=["operations"], generate_unique_id_function=operation_id)


@router.get(
    "/metrics",
    response_class=Response,
    responses={200: {"content": {"text/plain": {"schema": {"type": "string"}}}}},
)
async def metrics(request: Request, registry: MetricsDep) -> Response:
    """Requests by route, model and status; latency per model and pipeline stage; capacity."""
    body, content_type = registry.exposition(request.headers.get("accept"))
    return Response(content=body, media_type=content_type)
