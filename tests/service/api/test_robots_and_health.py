"""GET /robots, /healthz, /readyz and /docs: the served models and their manifest facts."""

from fastapi.testclient import TestClient


def test_robots_lists_every_model_with_its_manifest_facts(client: TestClient) -> None:
    response = client.get("/robots")
    assert response.status_code == 200
    (model,) = [m for m in response.json()["models"] if m["robot"] == "planar3r"]
    assert model["task"] == "position" and model["redundancy"] == 1
    assert model["periodic_joints"] == [True, True, True]
    assert model["target_position_length"] == 2 and model["orientation"] is False
    assert model["training"]["samples"] > 0 and model["training"]["wall_time_s"] > 0
    assert model["quality"]["held_out_targets"] == 200


def test_health_and_readiness(client: TestClient) -> None:
    assert client.get("/healthz").json() == {"status": "alive"}
    ready = client.get("/readyz")
    assert ready.status_code == 200 and ready.json()["status"] == "ready"
    assert any(m.startswith("planar3r-position@") for m in ready.json()["models"])


def test_openapi_documents_the_contract(client: TestClient) -> None:
    assert client.get("/docs").status_code == 200
    spec = client.get("/openapi.json").json()
    assert {"/smm", "/robots", "/healthz", "/readyz"} <= set(spec["paths"])
