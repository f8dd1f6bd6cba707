"""The FastAPI application: `create_app()` and the `smm-serve` entry point."""

from __future__ import annotations

import ctypes
import logging
import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from importlib import metadata
from typing import Any

import uvicorn
from fastapi import FastAPI

from service.api import health, metrics, robots, self_motion, smm, smm_batch
from service.config import Settings
from service.http.admission import Admission
from service.http.auth import ApiKeyMiddleware
from service.http.handlers import install_exception_handlers
from service.http.limits import RequestLimitsMiddleware
from service.http.openapi import served_openapi
from service.http.paths import API_PATHS, JSON_BODY_ROUTES
from service.http.request_context import RequestContextMiddleware
from service.models import int8_mlp
from service.models.registry import Registry, flow_kernel
from service.observability.logs import configure_logging, log_event
from service.observability.metrics import Metrics
from service.pipeline import native

# glibc's malloc.h: the parameters of mallopt that cap the number of arenas and fix the
# size from which a block is mapped on its own (and unmapped when freed).
M_ARENA_MAX = -8
M_MMAP_THRESHOLD = -3


def _mallopt(parameter: int, value: int) -> bool:
    """glibc's mallopt; whether it took effect (a C library other than glibc has none)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(parameter, value))
    except (OSError, AttributeError):
        return False


def limit_malloc_arenas(count: int) -> bool:
    """Cap glibc's malloc arenas at `count` (Settings.malloc_arenas says why); whether it
    took effect (0 asks for nothing)."""
    return count > 0 and _mallopt(M_ARENA_MAX, count)


def fix_mmap_threshold(size_bytes: int) -> bool:
    """Map every block of at least `size_bytes` on its own, for good (Settings.
    malloc_mmap_threshold_bytes says why); whether it took effect (0 asks for nothing and
    leaves glibc's threshold, which rises to the size of each mapped block freed)."""
    return size_bytes > 0 and _mallopt(M_MMAP_THRESHOLD, size_bytes)


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    # Before any model starts a thread: an arena is taken at a thread's first allocation.
    limit_malloc_arenas(settings.malloc_arenas)
    fix_mmap_threshold(settings.malloc_mmap_threshold_bytes)
    int8_mlp.keep_scratch(settings.flow_scratch_bytes)
    spin_s = settings.row_helper_spin_us * 1e-6
    native.set_helper_spin(spin_s)
    int8_mlp.set_helper_spin(spin_s)
    logger = configure_logging(settings.log_level)
    app_metrics = Metrics()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        # Load and verify every model before serving. A model that fails verification is
        # logged by name and listed by /readyz, which then does not claim readiness.
        registry = Registry.load(
            settings.models_dir, settings.onnx_threads_per_session, settings.compiled_int8
        )
        for model in registry.all():
            app_metrics.model_ready.labels(model.manifest.model_id).set(1)
            flow = flow_kernel(model.velocity)
            log_event(logger, logging.INFO, "model loaded", model=model.reference, flow=flow)
        for failure in registry.failed:
            app_metrics.model_ready.labels(failure.name).set(0)
            log_event(
                logger,
                logging.ERROR,
                "model failed verification; not served",
                model=failure.name,
                reason=failure.reason,
            )
        admission = Admission(
            settings.max_in_flight,
            settings.max_queued,
            settings.max_queue_wait_s,
            settings.retry_after_s,
        )
        app_metrics.track_capacity(lambda: admission.in_flight, lambda: admission.waiting)
        app.state.admission = admission
        app.state.registry = registry
        app.state.draining = False
        yield
        # The server stops taking connections and lets requests in flight finish before
        # this point; say so to any prober still connected.
        app.state.draining = True
        log_event(logger, logging.INFO, "shut down", in_flight=admission.in_flight)

    app = FastAPI(
        title="SMM service",
        summary="Self-motion manifolds of redundant robot arms.",
        version=metadata.version("smm-service"),  # pyproject.toml's, as CHANGELOG.md's
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.metrics = app_metrics
    install_exception_handlers(app)
    app.include_router(smm.router)
    app.include_router(smm_batch.router)
    app.include_router(self_motion.router)
    app.include_router(robots.router)
    app.include_router(health.router)
    app.include_router(metrics.router)
    app.openapi = lambda: served_openapi(app)  # type: ignore[method-assign]

    # Middlewares, innermost first: limits, then the API key, then the request context
    # (request id, access log, metrics), so that every refusal is logged and counted.
    app.add_middleware(
        RequestLimitsMiddleware,
        json_routes=JSON_BODY_ROUTES,
        max_body_bytes=settings.max_body_bytes,
        max_open_requests=settings.max_open_requests,
        retry_after_s=settings.retry_after_s,
        on_reject=lambda reason: app_metrics.rejected.labels(reason).inc(),
    )
    if settings.api_key is not None:
        app.add_middleware(ApiKeyMiddleware, api_key=settings.api_key.get_secret_value())
    app.add_middleware(
        RequestContextMiddleware, metrics=app_metrics, logger=logger, known_paths=API_PATHS
    )
    return app


def serve() -> None:
    """Console entry point `smm-serve`: run uvicorn with the settings from the environment.

    It binds SMM_HOST:SMM_PORT and runs SMM_WORKERS processes; with more than one, each
    worker builds its own app from the same environment. uvicorn's own access log is
    off: the service writes one JSON line per request, with its request id. On SIGTERM
    uvicorn stops accepting connections and waits up to SMM_SHUTDOWN_DRAIN_S for the
    requests in flight to finish. This is the container's command (Dockerfile).
    """
    settings = Settings()
    options: dict[str, Any] = {
        "host": settings.host,
        "port": settings.port,
        "log_level": settings.log_level,
        "access_log": False,
        "timeout_graceful_shutdown": math.ceil(settings.shutdown_drain_s),
    }
    if settings.workers == 1:
        uvicorn.run(create_app(settings), **options)
    else:
        # Worker processes import the app by name: an app object cannot be shared.
        uvicorn.run("service.main:create_app", factory=True, workers=settings.workers, **options)
