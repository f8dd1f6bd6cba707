"""The FastAPI application: `create_app()` and the `smm-serve` entry point."""

from __future__ import annotations

import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

import uvicorn
from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from service.api import health, robots, smm
from service.config import Settings
from service.errors import RequestFieldError, SmmError
from service.registry import Registry


def _error_response(request: Request, error: Exception) -> JSONResponse:
    assert isinstance(error, SmmError)
    if isinstance(error, RequestFieldError):
        # The same shape as FastAPI's own validation errors, so clients parse one format.
        detail: object = [
            {"loc": list(error.location), "msg": error.message, "type": "value_error"}
        ]
    else:
        detail = str(error)
    return JSONResponse({"detail": detail}, status_code=error.status_code)


def _json_safe(value: object) -> object:
    """Non-finite floats (which JSON cannot carry) become strings; containers recurse."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {key: _json_safe(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(item) for item in value]
    return value


def _validation_error_response(request: Request, error: Exception) -> JSONResponse:
    # FastAPI's default handler echoes the offending input, which fails to serialise
    # (a 500) when that input is NaN or infinity.
    assert isinstance(error, RequestValidationError)
    detail = _json_safe(jsonable_encoder(error.errors()))
    return JSONResponse({"detail": detail}, status_code=422)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # Load and verify every model before serving; a broken model stops start-up.
        app.state.registry = Registry.load(settings.models_dir, settings.onnx_threads)
        yield

    app = FastAPI(
        title="SMM service",
        summary="Self-motion manifolds of redundant robot arms.",
        version="0.1.0",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.add_exception_handler(SmmError, _error_response)
    app.add_exception_handler(RequestValidationError, _validation_error_response)
    app.include_router(smm.router)
    app.include_router(robots.router)
    app.include_router(health.router)
    return app


def serve() -> None:
    """Console entry point `smm-serve`: run uvicorn with the settings from the environment."""
    settings = Settings()
    uvicorn.run(
        create_app(settings), host=settings.host, port=settings.port, log_level=settings.log_level
    )
