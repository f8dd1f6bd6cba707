"""auth: with SMM_API_KEY set, every route but the probes and /metrics needs the key (401).

Without a key configured nothing is asked; with one, the key works in X-API-Key or as a
Bearer token, a wrong or missing key gets 401 on every other path (unknown ones and the
OpenAPI document included), and the probes and /metrics stay open for orchestrators.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from service.config import Settings
from service.http.auth import API_KEY_HEADER
from service.manifest import REPO_MODELS_DIR
from tests.support.app import make_client

KEY = "s3cret-key-for-tests"
BODY = {
    "robot": "planar3r",
    "task": "position",
    "target": {"position": [0.5, 0.0]},
    "num_samples": 20,
}


@pytest.fixture(scope="module")
def keyed() -> Iterator[TestClient]:
    with make_client(REPO_MODELS_DIR, api_key=KEY) as client:
        yield client


@pytest.mark.parametrize(
    ("method", "path"),
    [
        ("POST", "/smm"),
        ("GET", "/robots"),
        ("GET", "/docs"),
        ("GET", "/openapi.json"),
        ("GET", "/nowhere"),
    ],
)
@pytest.mark.parametrize(
    "headers",
    [{}, {API_KEY_HEADER: "wrong"}, {"Authorization": "Bearer wrong"}, {"Authorization": KEY}],
)
def test_protected_paths_refuse_a_missing_or_wrong_key(
    keyed: TestClient, method: str, path: str, headers: dict[str, str]
) -> None:
    response = keyed.request(method, path, json=BODY, headers=headers)
    assert response.status_code == 401
    assert response.json()["detail"].startswith(
        "missing or wrong API key: send it in the X-API-Key"
    )
    assert response.headers["www-authenticate"] == 'ApiKey header="X-API-Key"'
    assert response.headers["x-request-id"]


@pytest.mark.parametrize("headers", [{API_KEY_HEADER: KEY}, {"Authorization": f"Bearer {KEY}"}])
def test_the_key_opens_every_route(keyed: TestClient, headers: dict[str, str]) -> None:
    assert keyed.post("/smm", json=BODY, headers=headers).status_code == 200
    assert keyed.get("/robots", headers=headers).status_code == 200
    assert keyed.get("/openapi.json", headers=headers).status_code == 200


def test_probes_and_metrics_stay_open(keyed: TestClient) -> None:
    assert keyed.get("/healthz").status_code == 200
    assert keyed.get("/readyz").status_code == 200
    assert keyed.get("/metrics").status_code == 200


def test_no_key_configured_asks_for_none(client: TestClient) -> None:
    assert client.post("/smm", json=BODY).status_code == 200


def test_an_empty_variable_means_no_key(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SMM_API_KEY", "")
    assert Settings().api_key is None
    monkeypatch.setenv("SMM_API_KEY", KEY)
    key = Settings().api_key
    assert key is not None and key.get_secret_value() == KEY
    assert KEY not in repr(Settings())  # a secret, never printed
