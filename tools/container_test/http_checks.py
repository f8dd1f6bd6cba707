"""The checks over HTTP against the server the image's CMD runs: health, readiness with
every bundled model, a POST /smm per model checked by its independent FK, and the
settings that reach the process from the environment."""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable
from typing import Any

import httpx

from tools.container_test.outcomes import Checks
from tools.container_test.targets import TARGETS, bundled_models, check_answer

# Settings passed to the container as environment variables, and checked.
API_KEY = secrets.token_hex(16)
MAX_NUM_SAMPLES = 2000


def run_http_checks(
    url: str, key: dict[str, str], checks: Checks, figures: dict[str, Any]
) -> list[str]:
    """The HTTP checks against a running server; the request ids of their requests."""
    request_ids: list[str] = []
    with httpx.Client(base_url=url, timeout=60.0) as client:

        def get(path: str, **kwargs: Any) -> httpx.Response:
            response = client.get(path, **kwargs)
            request_ids.append(response.headers.get("x-request-id", "missing"))
            return response

        def post(body: dict[str, Any], **kwargs: Any) -> httpx.Response:
            response = client.post("/smm", json=body, **kwargs)
            request_ids.append(response.headers.get("x-request-id", "missing"))
            return response

        with checks.check("GET /healthz answers 200") as note:
            response = get("/healthz")
            assert response.status_code == 200, response.text
            note["detail"] = response.text

        served: dict[str, str] = {}
        with checks.check("GET /readyz answers 200 with every bundled model verified") as note:
            response = get("/readyz")
            assert response.status_code == 200, response.text
            readiness = response.json()
            served = {m.split("@")[0]: m for m in readiness["models"]}
            assert sorted(served) == bundled_models(), f"served {sorted(served)}"
            assert readiness["failed"] == [], readiness["failed"]
            note["detail"] = ", ".join(readiness["models"])

        for model_id in bundled_models():
            with checks.check(
                f"POST /smm {model_id}: answers verified by an independent FK"
            ) as note:
                elapsed_ms, note["detail"] = post_and_check(post, model_id, served, key)
                figures.setdefault("first_request_ms", {})[model_id] = round(elapsed_ms)

        with checks.check("SMM_API_KEY from the environment: 401 without the key") as note:
            response = post(TARGETS["planar3r-position"]().body)
            assert response.status_code == 401, response.status_code
            note["detail"] = response.json()["detail"]

        with checks.check("SMM_MAX_NUM_SAMPLES from the environment: 413 beyond it") as note:
            body = {**TARGETS["planar3r-position"]().body, "num_samples": MAX_NUM_SAMPLES + 1}
            response = post(body, headers=key)
            assert response.status_code == 413, response.status_code
            note["detail"] = str(response.json()["detail"])[:120]
    return request_ids


def post_and_check(
    post: Callable[..., httpx.Response],
    model_id: str,
    served: dict[str, str],
    headers: dict[str, str],
) -> tuple[float, str]:
    """POST /smm for a bundled model and check the answer by its independent FK; (ms, detail)."""
    assert model_id in TARGETS, f"no independent check for bundled model {model_id}"
    target = TARGETS[model_id]()
    started = time.perf_counter()
    response = post(target.body, headers=headers)
    elapsed_ms = (time.perf_counter() - started) * 1e3
    assert response.status_code == 200, f"{response.status_code} {response.text[:300]}"
    answer = response.json()
    assert answer["model"] == served.get(model_id), answer["model"]
    return elapsed_ms, check_answer(model_id, target, answer) + f", {elapsed_ms:.0f} ms"
