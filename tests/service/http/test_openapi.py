"""openapi: the document names the served robots and tasks, and every error a route
answers; each line of a batch's NDJSON answer is valid against the document's schema for
its lines (jsonschema, the reference validator, resolving the document's references)."""

from __future__ import annotations

import json
from typing import Any

from fastapi.testclient import TestClient
from jsonschema import Draft202012Validator
from referencing import Registry, Resource
from referencing.jsonschema import DRAFT202012

from service.wire import NDJSON
from tests.support.bundled import bundled_robots


def test_served_names_are_enums_and_errors_are_documented(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    request = spec["components"]["schemas"]["SmmRequest"]["properties"]
    assert request["robot"]["enum"] == bundled_robots()
    assert request["task"]["enum"] == ["axis", "pose", "position"]
    smm = spec["paths"]["/smm"]["post"]["responses"]
    assert set(smm) == {"200", "400", "401", "404", "413", "415", "422", "503", "504"}
    assert "Retry-After" in smm["503"]["headers"]
    assert set(spec["paths"]["/readyz"]["get"]["responses"]) == {"200", "503"}
    assert "text/plain" in spec["paths"]["/metrics"]["get"]["responses"]["200"]["content"]


def test_the_documented_version_is_the_package_version() -> None:
    """The OpenAPI document's version is pyproject.toml's, the one CHANGELOG.md releases."""
    import tomllib
    from pathlib import Path

    from service.main import create_app

    root = Path(__file__).resolve().parents[3]
    version = tomllib.loads((root / "pyproject.toml").read_text())["project"]["version"]
    assert create_app().openapi()["info"]["version"] == version
    assert f"## [{version}]" in (root / "CHANGELOG.md").read_text()


def line_validator(spec: dict[str, Any]) -> Draft202012Validator:
    """The document's schema of POST /smm/batch's NDJSON lines, its references resolved
    in the document itself."""
    document = Resource.from_contents(spec, default_specification=DRAFT202012)
    registry: Registry = Registry().with_resource("urn:smm-openapi", document)
    lines = "/paths/~1smm~1batch/post/responses/200/content/application~1x-ndjson/schema"
    return Draft202012Validator({"$ref": f"urn:smm-openapi#{lines}"}, registry=registry)


def test_every_line_of_a_streamed_batch_is_valid_against_the_document(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    validator = line_validator(spec)
    body = {
        "robot": "planar3r",
        "task": "position",
        "num_samples": 60,
        "targets": [{"target": {"position": [0.5, 0.0]}}, {"target": {"position": [3.5, 0.0]}}],
    }
    response = client.post("/smm/batch", json=body, headers={"Accept": NDJSON})
    lines = [json.loads(line) for line in response.text.splitlines()]
    assert len(lines) == 4  # head, two items, end
    for line in lines:
        validator.validate(line)
    # Each line is exactly one of the three: a wrong field is refused.
    assert not validator.is_valid({**lines[-1], "status": "done"})
    assert not validator.is_valid({"index": 0})
