"""Faults stay in their request: a network that returns NaN, served by the real app.

A planar 3R model whose served flow network (flow.onnx, or flow_int8.onnx where its
sampler's precision is int8) is a real ONNX graph that answers NaN for most
samples (the square root of its input: NaN wherever a coordinate is negative) is
served next to the healthy iiwa14 position model. Its requests get 200 with every
sample accounted for and only exact configurations returned (checked by the closed-form
FK), the process keeps serving, and the healthy model's answer under concurrent faulty
requests is identical to its answer alone.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import onnx
from onnx import TensorProto, helper

from service.manifest import FLOW_FILES, REPO_MODELS_DIR
from tests.support.app import PLANAR3R_DIR, make_client
from training.evaluate.references.planar3r import planar3r_position

IIWA_BODY = {
    "robot": "iiwa14",
    "task": "position",
    "target": {"position": [0.5, 0.0, 0.6]},
    "num_samples": 300,
    "seed": 3,
}
PLANAR_BODY = {"robot": "planar3r", "task": "position", "target": {"position": [1.2, 0.4]}}


def nan_flow(path: Path, joints: int, condition: int) -> None:
    """flow.onnx with the service's interface whose velocity is sqrt(q_t): NaN where q_t < 0."""
    inputs = [
        helper.make_tensor_value_info("q_t", TensorProto.FLOAT, ["B", joints]),
        helper.make_tensor_value_info("t", TensorProto.FLOAT, ["B", 1]),
        helper.make_tensor_value_info("condition", TensorProto.FLOAT, ["B", condition]),
    ]
    output = helper.make_tensor_value_info("velocity", TensorProto.FLOAT, ["B", joints])
    graph = helper.make_graph(
        [helper.make_node("Sqrt", ["q_t"], ["velocity"])], "nan_flow", inputs, [output]
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, path)


def faulty_models(tmp_path: Path) -> Path:
    models = tmp_path / "models"
    shutil.copytree(REPO_MODELS_DIR / "robots", models / "robots")
    shutil.copytree(REPO_MODELS_DIR / "iiwa14-position", models / "iiwa14-position")
    planar = models / PLANAR3R_DIR.name
    shutil.copytree(PLANAR3R_DIR, planar)
    manifest = json.loads((planar / "manifest.json").read_text())
    sampler = manifest["defaults"]["sampler"]
    served = FLOW_FILES[(sampler.get("flow", "base"), sampler.get("precision", "float32"))]
    nan_flow(planar / served, joints=3, condition=2)
    manifest["files"][served] = hashlib.sha256((planar / served).read_bytes()).hexdigest()
    (planar / "manifest.json").write_text(json.dumps(manifest))
    return models


def without_timings(answer: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in answer.items() if k != "timings_ms"}


def test_nan_from_the_network_is_contained_in_its_request(tmp_path: Path) -> None:
    with make_client(faulty_models(tmp_path)) as client:
        assert client.get("/readyz").status_code == 200  # the graph verifies: it is the fault
        alone = client.post("/smm", json=IIWA_BODY)
        assert alone.status_code == 200

        faulty = client.post("/smm", json=PLANAR_BODY)
        assert faulty.status_code == 200
        answer = faulty.json()
        counts = answer["counts"]
        sampled = counts["sampled"]  # at most 1000: the planar 3R draws in rounds
        assert 0 < sampled <= 1000
        # The NaN rows (7/8 of them) are rejected.
        assert counts["rejected_tolerance"] >= sampled // 2
        assert (
            counts["accepted"] + counts["rejected_tolerance"] + counts["rejected_joint_limits"]
            == sampled
        )
        # The few finite rows were corrected like any others: they must be exact.
        returned = [q for c in answer["components"] for q in c["configurations"]]
        assert returned
        error = np.linalg.norm(planar3r_position(np.array(returned)) - [1.2, 0.4], axis=1)
        assert error.max() <= 1e-6

        with ThreadPoolExecutor(4) as pool:
            faulty_futures = [pool.submit(client.post, "/smm", json=PLANAR_BODY) for _ in range(3)]
            healthy = pool.submit(client.post, "/smm", json=IIWA_BODY).result()
            assert all(f.result().status_code == 200 for f in faulty_futures)
        assert healthy.status_code == 200
        assert without_timings(healthy.json()) == without_timings(alone.json())
        assert client.get("/healthz").status_code == 200
