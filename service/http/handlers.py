"""Exception handlers: every error the service answers, in FastAPI's `{"detail": ...}` shape.

Domain exceptions (`service/errors.py`) carry their own status; a request field error
takes the shape of FastAPI's validation errors, so clients parse one format; validation
errors name their field and what it allows; an unparseable body says why.
"""

from __future__ import annotations

import math
from functools import cache
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException as StarletteHTTPException

from service.config import Settings
from service.errors import OverloadedError, RequestFieldError, RequestFieldErrors, SmmError
from service.http.validation import explain
from service.wire import SelfMotionRequest, SmmBatchRequest, SmmRequest

# The request model of each route that takes a body: validation messages quote its schema.
REQUEST_MODELS: dict[str, type[BaseModel]] = {
    "/smm": SmmRequest,
    "/smm/batch": SmmBatchRequest,
    "/smm/self-motion": SelfMotionRequest,
}


def request_schema(path: str) -> dict[str, Any]:
    """The JSON schema of the body of the route at `path` (SmmRequest's for any other)."""
    return _schema_of(REQUEST_MODELS.get(path, SmmRequest))


@cache
def _schema_of(model: type[BaseModel]) -> dict[str, Any]:
    # Built once per model: pydantic takes milliseconds to generate it, several times the
    # rest of a 422's handling, and a stream of malformed requests would pay it each time.
    # Read only (service/http/validation.py never writes to it).
    return model.model_json_schema()


def _field_error(error: RequestFieldError) -> dict[str, object]:
    return {"loc": list(error.location), "msg": error.message, "type": "value_error"}


def _error_response(request: Request, error: Exception) -> JSONResponse:
    assert isinstance(error, SmmError)
    # A request field error takes the shape of FastAPI's own validation errors, so
    # clients parse one format.
    if isinstance(error, RequestFieldError):
        detail: object = [_field_error(error)]
    elif isinstance(error, RequestFieldErrors):
        detail = [_field_error(e) for e in error.errors]
    else:
        detail = str(error)
    headers = None
    if isinstance(error, OverloadedError):
        headers = {"Retry-After": str(error.retry_after_s)}
    return JSONResponse({"detail": detail}, status_code=error.status_code, headers=headers)


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
    # Each message names its field and what the field allows. FastAPI's default handler
    # also echoes the offending input, which fails to serialise (a 500) when that input
    # is NaN or infinity: made JSON-safe here.
    assert isinstance(error, RequestValidationError)
    settings: Settings = request.app.state.settings
    per_query = f"<= {settings.max_num_samples} (this server's limit)"
    limits = {"num_samples": per_query, "targets.num_samples": per_query}
    schema = request_schema(request.url.path)
    errors = [explain(e, schema, limits) for e in jsonable_encoder(error.errors())]
    return JSONResponse({"detail": _json_safe(errors)}, status_code=422)


def _http_error_response(request: Request, error: Exception) -> JSONResponse:
    # FastAPI answers a body that is JSON-shaped but unparseable (an integer of more than
    # Python's 4300 digits) with a bare "There was an error parsing the body": say why.
    assert isinstance(error, StarletteHTTPException)
    detail = error.detail
    if error.status_code == 400 and error.__cause__ is not None:
        reason = str(error.__cause__).split(";")[0]
        detail = (
            f"body: could not be parsed ({reason}); allowed: a JSON object, numbers of at "
            "most 4300 digits"
        )
    return JSONResponse({"detail": detail}, status_code=error.status_code, headers=error.headers)


def install_exception_handlers(app: FastAPI) -> None:
    app.add_exception_handler(SmmError, _error_response)
    app.add_exception_handler(RequestValidationError, _validation_error_response)
    app.add_exception_handler(StarletteHTTPException, _http_error_response)
