"""`smm-serve`, the container's command: uvicorn started from the SMM_ settings.

It binds SMM_HOST:SMM_PORT, turns uvicorn's own access log off (the service logs one
JSON line per request), gives uvicorn the graceful-shutdown bound SMM_SHUTDOWN_DRAIN_S,
and with SMM_WORKERS > 1 runs that many processes, each building the app by name.
onnxruntime's default threads are shared among every computation that may run at once.
"""

from __future__ import annotations

from typing import Any

import pytest
from fastapi import FastAPI

from service import main
from service.config import Settings


@pytest.fixture
def uvicorn_calls(monkeypatch: pytest.MonkeyPatch) -> list[tuple[Any, dict[str, Any]]]:
    calls: list[tuple[Any, dict[str, Any]]] = []
    monkeypatch.setattr(main.uvicorn, "run", lambda app, **kw: calls.append((app, kw)))
    monkeypatch.setenv("SMM_PORT", "9123")
    monkeypatch.setenv("SMM_HOST", "0.0.0.0")
    return calls


def test_one_worker_serves_the_app_with_settings_from_the_environment(
    uvicorn_calls: list[tuple[Any, dict[str, Any]]],
) -> None:
    main.serve()
    ((app, options),) = uvicorn_calls
    assert isinstance(app, FastAPI)
    assert options == {
        "host": "0.0.0.0",
        "port": 9123,
        "log_level": "info",
        "access_log": False,
        "timeout_graceful_shutdown": 35,
    }


def test_several_workers_each_build_the_app_by_name(
    uvicorn_calls: list[tuple[Any, dict[str, Any]]], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SMM_WORKERS", "3")
    monkeypatch.setenv("SMM_SHUTDOWN_DRAIN_S", "12.5")
    main.serve()
    ((app, options),) = uvicorn_calls
    assert app == "service.main:create_app"
    assert options["factory"] is True and options["workers"] == 3
    assert options["access_log"] is False and options["timeout_graceful_shutdown"] == 13


def test_default_onnx_threads_share_the_cores_among_workers(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr("service.config.os.cpu_count", lambda: 8)
    assert Settings(workers=1, max_in_flight=2).onnx_threads_per_session == 8
    assert Settings(workers=2, max_in_flight=4).onnx_threads_per_session == 4
    assert Settings(workers=16, max_in_flight=1).onnx_threads_per_session == 1
    assert Settings(workers=4, onnx_threads=3).onnx_threads_per_session == 3
