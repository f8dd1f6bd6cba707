"""http.limits: bodies are bounded and JSON, open requests are capped with a prompt 503.

The body limit holds for a chunked body that declares no length (cut off while being
read, never buffered beyond the limit); the cap on open requests answers 503 with
Retry-After at once while the probes and /metrics stay open; the routes the limits
treat as JSON-body routes are exactly the documented ones that take a body.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from typing import Any

from fastapi.testclient import TestClient

from service.http.limits import RequestLimitsMiddleware, is_json_content_type
from service.http.paths import API_PATHS, JSON_BODY_ROUTES
from service.manifest import REPO_MODELS_DIR
from tests.support.app import make_client

BODY = {"robot": "planar3r", "task": "position", "target": {"position": [0.5, 0.0]}}


def test_json_content_types() -> None:
    assert is_json_content_type("application/json")
    assert is_json_content_type("application/json; charset=utf-8")
    assert is_json_content_type("application/problem+json")
    assert not is_json_content_type("text/plain")
    assert not is_json_content_type("application/x-www-form-urlencoded")
    assert not is_json_content_type("")


def test_a_chunked_body_over_the_limit_is_cut_off_with_413() -> None:
    def chunks() -> Iterator[bytes]:
        yield b'{"robot": "planar3r", "task": "position", "target": {"position": [0.5, 0.0]}, '
        yield b'"reference_configuration": [' + b"0.0, " * 400
        yield b"0.0]}"

    with make_client(REPO_MODELS_DIR, max_body_bytes=1024) as client:
        response = client.post(
            "/smm", content=chunks(), headers={"content-type": "application/json"}
        )
        assert response.status_code == 413
        assert response.json()["detail"].startswith("body: at most 1024 bytes")
        small = client.post("/smm", json={**BODY, "num_samples": 20})
        assert small.status_code == 200


def test_documented_routes_match_the_middlewares_view(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    assert set(spec["paths"]) == API_PATHS
    with_body = {
        (method.upper(), path)
        for path, operations in spec["paths"].items()
        for method, operation in operations.items()
        if "requestBody" in operation
    }
    assert with_body == JSON_BODY_ROUTES


def test_open_requests_over_the_cap_get_a_prompt_503_and_probes_stay_open() -> None:
    async def scenario() -> list[tuple[str, int, dict[str, str], Any]]:
        release = asyncio.Event()

        async def slow_app(scope: Any, receive: Any, send: Any) -> None:
            await release.wait()
            await send({"type": "http.response.start", "status": 200, "headers": []})
            await send({"type": "http.response.body", "body": b"done"})

        rejected: list[str] = []
        limits = RequestLimitsMiddleware(
            slow_app,
            json_routes=frozenset(),
            max_body_bytes=1024,
            max_open_requests=2,
            retry_after_s=7,
            on_reject=rejected.append,
        )

        async def call(path: str) -> tuple[str, int, dict[str, str], Any]:
            sent: list[Any] = []

            async def receive() -> dict[str, Any]:
                return {"type": "http.request", "body": b"", "more_body": False}

            async def send(message: Any) -> None:
                sent.append(message)

            scope = {"type": "http", "method": "GET", "path": path, "headers": []}
            await limits(scope, receive, send)
            start = sent[0]
            headers = {k.decode(): v.decode() for k, v in start["headers"]}
            return path, start["status"], headers, sent[1]["body"]

        held = [asyncio.create_task(call("/robots")) for _ in range(2)]
        await asyncio.sleep(0.01)
        refused = await asyncio.wait_for(call("/robots"), timeout=1.0)  # at once
        probe = asyncio.create_task(call("/healthz"))  # not capped: waits like the others
        await asyncio.sleep(0.01)
        assert limits.open_requests == 2 and rejected == ["open_requests"]
        release.set()
        return [refused, *await asyncio.gather(*held, probe)]

    refused, *answered = asyncio.run(scenario())
    assert refused[1] == 503 and refused[2]["retry-after"] == "7"
    assert "SMM_MAX_OPEN_REQUESTS=2" in json.loads(refused[3])["detail"]
    assert [status for _, status, _, _ in answered] == [200, 200, 200]
