"""Liveness and readiness probes (open even when an API key is set)."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

from service.http.openapi import operation_id
from service.wire import FailedModelOut, LivenessResponse, ReadinessResponse

router = APIRouter(tags=["health"], generate_unique_id_function=operation_id)


@router.get("/healthz", response_model=LivenessResponse)
async def healthz() -> LivenessResponse:
    """The process is alive (and its event loop answers)."""
    return LivenessResponse(status="alive")


@router.get(
    "/readyz",
    response_model=ReadinessResponse,
    responses={
        503: {
            "model": ReadinessResponse,
            "description": "Not ready: loading, draining, or a "
            "model failed verification (named in `failed`).",
        }
    },
)
async def readyz(request: Request) -> JSONResponse:
    """Ready when every model found was loaded and verified, and the server is not draining."""
    registry = getattr(request.app.state, "registry", None)
    if registry is None:
        answer = ReadinessResponse(status="loading", models=[], failed=[])
    else:
        draining = getattr(request.app.state, "draining", False)
        status = "draining" if draining else ("ready" if registry.ready else "not_ready")
        answer = ReadinessResponse(
            status=status,
            models=[m.reference for m in registry.all()],
            failed=[FailedModelOut(name=f.name, reason=f.reason) for f in registry.failed],
        )
    return JSONResponse(answer.model_dump(), status_code=200 if answer.status == "ready" else 503)
