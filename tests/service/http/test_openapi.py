"""openapi: the document names the served robots and tasks, and every error a route answers."""

from __future__ import annotations

from fastapi.testclient import TestClient

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
