"""The answers' JSON (service/api/answers.py), encoded by orjson from the pipeline's arrays.

Every answer the routes send (POST /smm with paths, a reference, collisions checked or not,
an r = 4 roadmap; a batch; a self-motion) validates as the route's pydantic model and
encodes again to the same JSON values; and the floats on the wire are the pipeline's
float64 to the bit (run in process with the same query and seed), so nothing is lost in
the encoding, whatever the arrays' memory layout.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from pydantic import BaseModel

from service.api.answers import component_fields, encode
from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.run import run
from service.pipeline.types import Query
from service.wire import SelfMotionResponse, SmmBatchResponse, SmmResponse
from training.evaluate.references.planar3r import closed_form_smm

SMM_BODIES: list[dict[str, Any]] = [
    {"robot": "planar3r", "task": "position", "target": {"position": [0.5, 0.0]},
     "reference_configuration": [0.1, 0.2, 0.3]},
    {"robot": "planar3r", "task": "position", "target": {"position": [9.0, 0.0]}},
    {"robot": "iiwa14", "task": "pose",
     "target": {"position": [0.4, 0.1, 0.6], "orientation": {"w": 0, "x": 0, "y": 1, "z": 0}}},
    {"robot": "iiwa14", "task": "position", "target": {"position": [0.4, 0.1, 0.6]},
     "num_samples": 300},
    {"robot": "iiwa14", "task": "position", "target": {"position": [0.4, 0.1, 0.6]},
     "num_samples": 300, "include_roadmap": True},
]  # fmt: skip


def same_values_again(model: type[BaseModel], content: bytes) -> Any:
    """The answer validated as `model`, and its values as pydantic encodes them again."""
    answer = json.loads(content)
    again = json.loads(model.model_validate_json(content).model_dump_json())
    assert again == answer
    return answer


def test_every_answer_validates_as_its_model_to_the_same_values(client: TestClient) -> None:
    for body in SMM_BODIES:
        response = client.post("/smm", json=body)
        assert response.status_code == 200, response.text
        same_values_again(SmmResponse, response.content)
    assert response.json()["components"][0]["roadmap"]["edges"]  # the r = 4 roadmap
    targets = [{"target": {"position": [0.5, y]}} for y in (0.0, 0.3)]
    body = {"robot": "planar3r", "task": "position", "targets": targets}
    response = client.post("/smm/batch", json=body)
    assert response.status_code == 200, response.text
    assert len(same_values_again(SmmBatchResponse, response.content)["results"]) == 2
    loop = closed_form_smm(np.array([0.5, 0.0]), 0.01)[0]  # (K, 3) one exact loop
    body = {
        "robot": "planar3r",
        "task": "position",
        "target": {"position": [0.5, 0.0]},
        "start": loop[10].tolist(),
        "goal": {"configuration": loop[300].tolist()},
    }
    response = client.post("/smm/self-motion", json=body)
    assert response.status_code == 200, response.text
    assert same_values_again(SelfMotionResponse, response.content)["path"]


@pytest.fixture(scope="module")
def iiwa14_pose() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)


def test_the_wire_floats_are_the_pipelines_to_the_bit(
    client: TestClient, iiwa14_pose: ServedModel
) -> None:
    body = SMM_BODIES[2]
    answer = client.post("/smm", json={**body, "seed": 3}).json()
    target = body["target"]
    orientation = target["orientation"]
    query = Query.for_model(
        iiwa14_pose.manifest,
        position_m=target["position"],
        orientation_wxyz=tuple(orientation[k] for k in "wxyz"),
        seed=3,
    )
    result = run(iiwa14_pose, query)
    assert len(answer["components"]) == len(result.components) > 0
    for sent, summary in zip(answer["components"], result.components, strict=True):
        assert summary.path is not None
        assert np.array_equal(np.array(sent["path"]), summary.path.q_rad)
        assert np.array_equal(np.array(sent["configurations"]), summary.configurations_rad)
        assert sent["max_position_error"] == summary.max_position_error_m


def test_arrays_of_any_layout_encode_as_their_values(iiwa14_pose: ServedModel) -> None:
    """A transposed or strided view (orjson takes C-contiguous arrays only) encodes as the
    same numbers as its contiguous copy."""
    query = Query.for_model(
        iiwa14_pose.manifest,
        position_m=[0.4, 0.1, 0.6],
        orientation_wxyz=(0.0, 0.0, 1.0, 0.0),
        num_samples=200,
    )
    summary = run(iiwa14_pose, query).components[0]
    strided = np.asfortranarray(summary.configurations_rad)[::2]
    assert not strided.flags.c_contiguous
    view = type(summary)(**{**vars(summary), "configurations_rad": strided})
    sent = json.loads(encode(component_fields(0, view)))
    assert np.array_equal(np.array(sent["configurations"]).reshape(-1, 7), strided)
