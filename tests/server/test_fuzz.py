"""Property-based fuzz of the OpenAPI contract against a real server (schemathesis).

Schemathesis generates requests from the server's own /openapi.json, schema-valid ones
and schema-violating ones, for every documented operation, and sends them to a real
uvicorn process (POST /smm/batch and POST /smm/self-motion too, on a server that admits
4 targets of at most 200 samples). Most of those stop at validation (a position of the
wrong length for the model, say), so a second generator shapes bodies after each served
model (from GET /robots) with arbitrary finite numbers everywhere, to drive the pipeline itself with
extreme targets, references and tolerances. Every response must be no 5xx, have a
documented status, content type and headers, and match the documented schema; a
schema-violating request must be refused with a 4xx. At least 500 generated requests
are sent; the test prints how many, and by status.
"""

from __future__ import annotations

import time
from collections import Counter
from typing import Any

import httpx
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    negative_data_rejection,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

from tests.server.conftest import FUZZ_MAX_BATCH_TARGETS, FUZZ_MAX_NUM_SAMPLES
from tools.local_server import LocalServer

FINITE = st.floats(allow_nan=False, allow_infinity=False)

MIN_REQUESTS = 500
EXAMPLES = {GenerationMode.POSITIVE: 450, GenerationMode.NEGATIVE: 250}
# POST /smm/batch: its targets go through POST /smm's checks, so fewer examples suffice.
BATCH_EXAMPLES = {GenerationMode.POSITIVE: 100, GenerationMode.NEGATIVE: 60}
# POST /smm/self-motion: POST /smm's body and checks, with a start and a goal.
SELF_MOTION_EXAMPLES = {GenerationMode.POSITIVE: 60, GenerationMode.NEGATIVE: 40}
OTHER_OPERATION_EXAMPLES = 10
MODEL_SHAPED_EXAMPLES = 150
MODEL_SHAPED_BATCH_EXAMPLES = 30
TIME_BUDGET_S = 240.0  # a generous bound: the run takes ~30 s on 2 cores
CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_headers_conformance,
    response_schema_conformance,
]


def model_shaped_body(model: dict[str, Any]) -> st.SearchStrategy[dict[str, Any]]:
    """Bodies of the right shape for one served model (GET /robots), numbers arbitrary."""
    joints = len(model["joint_names"])
    quaternion = (
        st.tuples(*[st.floats(-1, 1)] * 4)
        .filter(lambda q: sum(v * v for v in q) > 0.1)
        .map(lambda q: [v / sum(u * u for u in q) ** 0.5 for v in q])
    )
    target = st.fixed_dictionaries(
        {
            "position": st.lists(
                FINITE | st.floats(-3, 3),
                min_size=model["target_position_length"],
                max_size=model["target_position_length"],
            )
        }
        | (
            {"orientation": quaternion.map(lambda q: dict(zip("wxyz", q, strict=True)))}
            if model["orientation"]
            else {}
        )
    )
    tolerance = {"position": st.floats(1e-15, 0.1)}
    if model["orientation"]:
        tolerance["orientation"] = st.floats(1e-15, 3.14)
    return st.fixed_dictionaries(
        {
            "robot": st.just(model["robot"]),
            "task": st.just(model["task"]),
            "target": target,
            # Always given: the model's default (1000) is over this server's limit.
            "num_samples": st.integers(1, FUZZ_MAX_NUM_SAMPLES),
        },
        optional={
            "seed": st.integers(0, 2**63 - 1),
            "tolerance": st.fixed_dictionaries({}, optional=tolerance),
            "reference_configuration": st.lists(
                FINITE | st.floats(-4, 4), min_size=joints, max_size=joints
            ),
            "max_configurations_per_component": st.integers(1, 50),
        },
    )


def model_shaped_batch(model: dict[str, Any]) -> st.SearchStrategy[dict[str, Any]]:
    """Batches of 1 to FUZZ_MAX_BATCH_TARGETS model-shaped bodies' targets and options."""

    def as_batch(bodies: list[dict[str, Any]]) -> dict[str, Any]:
        targets = [{k: v for k, v in b.items() if k not in ("robot", "task")} for b in bodies]
        return {"robot": model["robot"], "task": model["task"], "targets": targets}

    bodies = st.lists(model_shaped_body(model), min_size=1, max_size=FUZZ_MAX_BATCH_TARGETS)
    return bodies.map(as_batch)


def test_generated_requests_get_no_5xx_and_documented_answers(server: LocalServer) -> None:
    schema = schemathesis.openapi.from_url(f"{server.url}/openapi.json")
    statuses: Counter[int] = Counter()
    start = time.monotonic()

    def fuzz(operation: schemathesis.APIOperation, mode: GenerationMode, examples: int) -> None:
        checks = CHECKS + ([negative_data_rejection] if mode is GenerationMode.NEGATIVE else [])

        @given(case=operation.as_strategy(generation_mode=mode))
        @settings(
            max_examples=examples,
            deadline=None,
            database=None,
            phases=[Phase.explicit, Phase.generate],  # no shrinking against a live server
            suppress_health_check=list(HealthCheck),
        )
        def one(case: schemathesis.Case) -> None:
            assert time.monotonic() - start < TIME_BUDGET_S, "fuzz ran past its time budget"
            response = case.call(base_url=server.url, timeout=60)
            statuses[response.status_code] += 1
            case.validate_response(response, checks=checks)

        one()

    smm = schema["/smm"]["POST"]
    for mode, examples in EXAMPLES.items():
        fuzz(smm, mode, examples)
    for mode, examples in BATCH_EXAMPLES.items():
        fuzz(schema["/smm/batch"]["POST"], mode, examples)
    for mode, examples in SELF_MOTION_EXAMPLES.items():
        fuzz(schema["/smm/self-motion"]["POST"], mode, examples)
    for path in ("/robots", "/healthz", "/readyz", "/metrics"):
        fuzz(schema[path]["GET"], GenerationMode.POSITIVE, OTHER_OPERATION_EXAMPLES)

    models = httpx.get(f"{server.url}/robots").json()["models"]

    @given(body=st.one_of([model_shaped_body(m) for m in models]))
    @settings(
        max_examples=MODEL_SHAPED_EXAMPLES,
        deadline=None,
        database=None,
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    def model_shaped(body: dict[str, Any]) -> None:
        assert time.monotonic() - start < TIME_BUDGET_S, "fuzz ran past its time budget"
        case = smm.Case(body=body, media_type="application/json")
        response = case.call(base_url=server.url, timeout=60)
        statuses[response.status_code] += 1
        case.validate_response(response, checks=CHECKS)

    model_shaped()

    batch = schema["/smm/batch"]["POST"]

    @given(body=st.one_of([model_shaped_batch(m) for m in models]))
    @settings(
        max_examples=MODEL_SHAPED_BATCH_EXAMPLES,
        deadline=None,
        database=None,
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    def model_shaped_batches(body: dict[str, Any]) -> None:
        assert time.monotonic() - start < TIME_BUDGET_S, "fuzz ran past its time budget"
        case = batch.Case(body=body, media_type="application/json")
        response = case.call(base_url=server.url, timeout=60)
        statuses[response.status_code] += 1
        case.validate_response(response, checks=CHECKS)

    model_shaped_batches()

    total = sum(statuses.values())
    print(f"fuzz: {total} requests in {time.monotonic() - start:.0f} s, by status {dict(statuses)}")
    assert total >= MIN_REQUESTS
    assert not [status for status in statuses if status >= 500]
    assert statuses[200] >= MODEL_SHAPED_EXAMPLES // 2  # the pipeline itself was fuzzed
    assert statuses[422] > 0
    assert httpx.get(f"{server.url}/healthz").status_code == 200
