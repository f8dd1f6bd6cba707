"""OpenAPI entries for the error statuses the routes answer.

The request and response models themselves are the wire format in `service/wire.py`,
shared with the Python client (`service.client`).
"""

from __future__ import annotations

from typing import Any

from service.wire import ErrorResponse


def error_responses(
    *statuses: int, meanings: dict[int, str] | None = None
) -> dict[int | str, dict[str, Any]]:
    """OpenAPI entries for the error statuses a route can answer, with their meaning
    (`meanings`: a route's own meaning of a status, instead of POST /smm's)."""
    meaning = {
        400: "The body could not be parsed at all.",
        401: "SMM_API_KEY is set and the request did not present it.",
        404: "Unknown robot or task; the message lists what is served.",
        413: "Body over SMM_MAX_BODY_BYTES, or num_samples over SMM_MAX_NUM_SAMPLES.",
        415: "Content-Type is not application/json.",
        503: "At capacity (Retry-After says when to retry), or the model failed verification.",
        504: "The request ran past SMM_REQUEST_DEADLINE_S.",
    }
    meaning.update(meanings or {})
    responses: dict[int | str, dict[str, Any]] = {}
    for status in statuses:
        responses[status] = {"model": ErrorResponse, "description": meaning[status]}
    if 503 in responses:
        responses[503]["headers"] = {
            "Retry-After": {
                "description": "Seconds to wait before retrying (when at capacity).",
                "schema": {"type": "integer"},
            }
        }
    return responses
