"""The OpenAPI document, completed with what only the loaded registry knows.

`robot` and `task` are plain strings in the request model (an unknown one is a 404
listing what is served), but the document names the served values as enums, so a
client generator or a fuzzer sees the real choices. It is built once the registry
has loaded and cached from then on.

Every route's operation id is its endpoint's name less a method prefix (`operation_id`), so
a generated client's functions read `smm`, `smm_batch`, `list_robots`, `healthz`,
`readyz` and `metrics` rather than FastAPI's `post_smm_smm_post`.

POST /smm/batch's NDJSON answer names the model of each line (`wire.BATCH_LINES`), so the
document holds those models too, though no route returns them whole.
"""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import APIRoute
from pydantic.json_schema import models_json_schema

from service.models.registry import Registry
from service.wire import BATCH_LINES


def operation_id(route: APIRoute) -> str:
    """A route's OpenAPI operation id: its endpoint's name less an HTTP method prefix
    (`post_smm` -> `smm`, `list_robots` and `healthz` as they are).

    Every router passes this as its `generate_unique_id_function`; FastAPI warns when
    two routes get the same id."""
    name = route.name
    for method in sorted(route.methods or ()):
        name = name.removeprefix(f"{method.lower()}_")
    return name


def served_openapi(app: FastAPI) -> dict[str, Any]:
    """app.openapi(): FastAPI's document with the served robot and task names as enums."""
    if app.openapi_schema is not None:
        return app.openapi_schema
    schema = get_openapi(
        title=app.title,
        version=app.version,
        summary=app.summary,
        description=app.description,
        routes=app.routes,
    )
    _add_line_models(schema)
    registry: Registry | None = getattr(app.state, "registry", None)
    if registry is None:  # not loaded yet: plain strings, and do not cache
        return schema
    for name in ("SmmRequest", "SmmBatchRequest"):
        request = schema["components"]["schemas"][name]["properties"]
        request["robot"]["enum"] = sorted({m.manifest.robot for m in registry.all()})
        request["task"]["enum"] = sorted({m.manifest.task.name for m in registry.all()})
    app.openapi_schema = schema
    return schema


def _add_line_models(schema: dict[str, Any]) -> None:
    """The models of the batch's NDJSON lines, and those they refer to, into the document's
    components where FastAPI left them out."""
    _, definitions = models_json_schema(
        [(model, "serialization") for model in BATCH_LINES],
        ref_template="#/components/schemas/{model}",
    )
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    for name, definition in definitions.get("$defs", {}).items():
        components.setdefault(name, definition)
