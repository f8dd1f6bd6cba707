"""validation: a 422 message names its field and says what the request schema allows there."""

from __future__ import annotations

from service.http.validation import describe, explain, field_path, node_at
from service.wire import SmmRequest

SCHEMA = SmmRequest.model_json_schema()


def test_field_paths_read_like_the_json() -> None:
    assert field_path(("body", "target", "position", 1)) == "target.position[1]"
    assert field_path(("body", "reference_configuration")) == "reference_configuration"
    assert field_path(("body",)) == "body"


def test_allowances_come_from_the_schema_bounds() -> None:
    tolerance = node_at(SCHEMA, ("body", "tolerance", "position"))
    assert tolerance is not None
    assert describe(tolerance, SCHEMA) == "a finite number > 0 and <= 0.1, or null / omitted"
    position = node_at(SCHEMA, ("body", "target", "position"))
    assert position is not None
    assert describe(position, SCHEMA) == "a list of 1 to 3 values, each a finite number"
    assert node_at(SCHEMA, ("body", "no_such_field")) is None


def test_messages_keep_the_error_and_add_field_and_allowance() -> None:
    error = {
        "type": "greater_than_equal",
        "loc": ("body", "num_samples"),
        "msg": "Input should be greater than or equal to 1",
        "input": 0,
    }
    explained = explain(error, SCHEMA, {"num_samples": "<= 50 (this server's limit)"})
    assert explained["loc"] == ("body", "num_samples") and explained["input"] == 0
    assert explained["msg"] == (
        "num_samples: Input should be greater than or equal to 1; "
        "allowed: an integer >= 1 and <= 50 (this server's limit), or null / omitted"
    )
    unknown = explain(
        {
            "type": "extra_forbidden",
            "loc": ("body", "tolerance", "pos"),
            "msg": "Extra inputs are not permitted",
        },
        SCHEMA,
        {},
    )
    assert unknown["msg"].endswith("allowed: only the fields position, orientation")


def test_a_routes_schema_is_its_request_models_built_once() -> None:
    from service.http.handlers import request_schema
    from service.wire import SmmBatchRequest

    assert request_schema("/smm/batch") == SmmBatchRequest.model_json_schema()
    assert request_schema("/smm") == SCHEMA
    # Any other path reads SmmRequest's; a repeated 422 reuses the schema, not a new one.
    assert request_schema("/elsewhere") is request_schema("/smm")
