"""Liveness and readiness probes."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse

router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz() -> dict[str, str]:
    """The process is alive."""
    return {"status": "alive"}


@router.get("/readyz")
def readyz(request: Request) -> JSONResponse:
    """Every model loaded and verified."""
    registry = getattr(request.app.state, "registry", None)
    if registry is None:
        return JSONResponse({"status": "loading"}, status_code=503)
    models = [m.reference for m in registry.all()]
    return JSONResponse({"status": "ready", "models": models})
