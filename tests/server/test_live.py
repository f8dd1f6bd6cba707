"""The catalogue of bad inputs, request ids and JSON logs, against a real uvicorn process.

Every catalogued bad input (docs/bad-inputs.md) gets its documented status and a
message naming the field and the allowance over real HTTP too (uvicorn's own parsing
included); every answer carries X-Request-ID, and the server's log has a JSON access
line with that id, route, model and status.
"""

from __future__ import annotations

import time

import httpx
import pytest

from service.models.registry import int8_flow_here
from tests.server.conftest import FUZZ_MAX_NUM_SAMPLES
from tests.support.bad_inputs import BadInput, catalogue, check_answer
from tests.support.bundled import bundled_model_ids
from tools.local_server import LocalServer

CATALOGUE = catalogue(FUZZ_MAX_NUM_SAMPLES, max_body_bytes=65_536)


@pytest.mark.parametrize("bad", CATALOGUE, ids=[b.id for b in CATALOGUE])
def test_bad_input_over_real_http(server: LocalServer, bad: BadInput) -> None:
    response = httpx.request(
        bad.method, f"{server.url}/smm", content=bad.content(), headers=bad.headers, timeout=30
    )
    check_answer(bad, response.status_code, response.json())
    assert response.headers["x-request-id"]


def test_answers_and_log_lines_share_the_request_id(server: LocalServer) -> None:
    body = {
        "robot": "iiwa14",
        "task": "position",
        "target": {"position": [0.5, 0.0, 0.6]},
        "num_samples": 100,
    }
    response = httpx.post(
        f"{server.url}/smm", json=body, headers={"X-Request-ID": "live-42"}, timeout=30
    )
    assert response.status_code == 200 and response.headers["x-request-id"] == "live-42"
    for _ in range(50):  # the line is written right after the response; give it a moment
        lines = [line for line in server.log_lines() if line.get("request_id") == "live-42"]
        if lines:
            break
        time.sleep(0.05)
    (access,) = lines
    assert access["message"] == "request" and access["status"] == 200
    assert access["route"] == "/smm" and access["model"] == "iiwa14-position"
    started = [line for line in server.log_lines() if line.get("message") == "model loaded"]
    assert len(started) == len(bundled_model_ids())
    # Every bundled model serves int8: on the compiled layers where AMX, VNNI or AVX2 is, naming it.
    assert {line["flow"] for line in started} == {int8_flow_here()}
