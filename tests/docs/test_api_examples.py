"""What the HTTP API pages say about their examples holds, against exact ground truth.

The prose beside each example states facts that `tests/docs/test_examples.py` cannot see
in the abbreviated output: the planar target's two loops are its closed-form SMM; the
iiwa14 pose's answer has every component of the exact S-R-S SMM, short ones that no
sample hit among them, none closed, the first nearest the reference, q4 constant on
each; the iiwa14 position's components are those of the exact 4-D reference, split by
the signs of q2 and q4, with no paths. Each request is the page's own curl body.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.config import Settings
from service.main import create_app
from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from service.pipeline.rotations import quaternion_to_matrix
from tools.docs.examples import Example, examples
from tools.docs.pages import ROOT
from training.evaluate.references import iiwa14
from training.evaluate.references.planar3r import expected_component_count

PAGES = [ROOT / "docs" / "api.md", ROOT / "docs" / "examples.md", ROOT / "docs" / "batch.md"]
EXAMPLES = {example.name: example for example in examples(PAGES)}


@pytest.fixture(scope="module")
def client() -> Iterator[TestClient]:
    with TestClient(create_app(Settings())) as test_client:
        yield test_client


def answer(client: TestClient, example: Example) -> dict[str, Any]:
    response = client.request(example.method, example.route, json=example.body)
    assert response.status_code == 200, response.text
    body: dict[str, Any] = response.json()
    return body


def test_the_planar_target_has_its_two_closed_loops(client: TestClient) -> None:
    example = EXAMPLES["planar3r-position"]
    rho = float(np.linalg.norm(example.body["target"]["position"]))
    components = answer(client, example)["components"]
    assert len(components) == expected_component_count(rho) == 2
    assert all(c["closed"] for c in components)
    assert {np.sign(c["representative"][1]) for c in components} == {-1.0, 1.0}  # elbows


def test_the_iiwa14_pose_has_every_exact_component(client: TestClient) -> None:
    example = EXAMPLES["iiwa14-pose"]
    target = example.body["target"]
    quaternion = np.array([target["orientation"][k] for k in "wxyz"])
    rotation = quaternion_to_matrix(*(quaternion / np.linalg.norm(quaternion)))
    exact = iiwa14.pose_smm(np.array(target["position"]), rotation)
    got = answer(client, example)
    components = got["components"]
    assert not got["structure"]["near_singular"]
    assert len(components) == len(exact)
    assert any(c["size"] == 0 for c in components)  # found by the tracing alone
    assert not any(c["closed"] for c in components)
    distances = [c["distance_to_reference"] for c in components]
    # The target is the reference's pose to 0.1 mm: the first component passes by it, so its
    # path comes within half a path spacing of it, the next ones only much further.
    spacing = Manifest.model_validate_json(
        (REPO_MODELS_DIR / "iiwa14-pose" / MANIFEST_FILE).read_text()
    ).defaults.connectivity.path_spacing_rad
    assert distances == sorted(distances) and distances[0] < spacing / 2 < distances[1]
    for component in components:
        path = np.array(component["path"])
        assert np.ptp(path[:, 3]) < 1e-6  # q4 fixed on a component ...
    assert len({np.sign(c["representative"][3]) for c in components}) == 2  # ... up to sign


def test_the_iiwa14_position_has_the_exact_4d_components(client: TestClient) -> None:
    example = EXAMPLES["iiwa14-position"]
    exact = iiwa14.position_smm(np.array(example.body["target"]["position"]))
    got = answer(client, example)
    components = got["components"]
    assert got["structure"]["traced"] is False
    assert len(components) == exact.count == 6
    assert all(c["path"] is None and c["closed"] is None for c in components)
    signs = []
    for component in components:
        low, high = np.array(component["joint_min"]), np.array(component["joint_max"])
        assert (np.sign(low[[1, 3]]) == np.sign(high[[1, 3]])).all()  # one sign each
        signs.append((np.sign(low[1]), np.sign(low[3])))
    assert signs.count((1.0, 1.0)) == signs.count((1.0, -1.0)) == 1
    assert signs.count((-1.0, 1.0)) == signs.count((-1.0, -1.0)) == 2  # cut in two


def test_the_batch_orders_the_second_target_by_its_reference(client: TestClient) -> None:
    results = answer(client, EXAMPLES["batch"])["results"]
    assert [r["status"] for r in results] == ["ok", "ok", "no_solution"]
    distances = [c["distance_to_reference"] for c in results[1]["answer"]["components"]]
    assert distances == sorted(distances)
    assert results[0]["answer"]["components"][0]["distance_to_reference"] is None
