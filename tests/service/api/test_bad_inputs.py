"""Every catalogued bad input (docs/bad-inputs.md) gets its documented status, in process.

Each answer's message must name the field and say what is allowed there; the catalogue
and the document's table must list the same inputs with the same statuses. The nearly
unit quaternion of the stated policy is accepted (normalised), not refused.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.support.bad_inputs import POSE, BadInput, catalogue, check_answer

DOC = Path(__file__).resolve().parents[3] / "docs" / "bad-inputs.md"
MAX_NUM_SAMPLES = 5000  # the session client's limit (tests/conftest.py)
MAX_BODY_BYTES = 65_536  # the default
CATALOGUE = catalogue(MAX_NUM_SAMPLES, MAX_BODY_BYTES)


def send(client: Any, bad: BadInput) -> Any:
    return client.request(bad.method, "/smm", content=bad.content(), headers=bad.headers)


@pytest.mark.parametrize("bad", CATALOGUE, ids=[b.id for b in CATALOGUE])
def test_bad_input_gets_its_status_and_a_message_naming_field_and_range(
    client: TestClient, bad: BadInput
) -> None:
    response = send(client, bad)
    check_answer(bad, response.status_code, response.json())


def test_the_document_lists_exactly_the_catalogue() -> None:
    rows = re.findall(r"^\| `([a-z0-9-]+)` \|.*\| (\d{3}) \|", DOC.read_text(), re.MULTILINE)
    assert rows, "no table rows found in docs/bad-inputs.md"
    assert {(name, int(status)) for name, status in rows} == {(b.id, b.status) for b in CATALOGUE}


@pytest.mark.parametrize("norm", [0.991, 1.0, 1.009])
def test_a_nearly_unit_quaternion_is_normalised_not_refused(
    client: TestClient, norm: float
) -> None:
    body = {
        **POSE,
        "target": {**POSE["target"], "orientation": {"w": 0.0, "x": norm, "y": 0.0, "z": 0.0}},
    }
    response = client.post("/smm", json=body)
    assert response.status_code == 200, response.text
    exact = client.post("/smm", json=POSE).json()
    assert response.json()["components"] == exact["components"]  # same rotation, same answer
