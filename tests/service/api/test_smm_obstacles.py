"""POST /smm and /smm/batch with a scene, on the real app: a model directory whose
collision.json (the planar 3R with a sphere per link) is verified and loaded like any
file of the manifest; answers clear of the obstacles by the closed-form FK; the collision
block and counts; bad obstacles, margins and too many obstacles refused with a 422 naming
the field; and obstacles refused for a model without collision geometry."""

from __future__ import annotations

import json
import shutil
from collections.abc import Iterator

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.manifest import COLLISION_FILE, MANIFEST_FILE
from service.models.registry import sha256_of
from service.wire import MAX_OBSTACLES
from tests.service.pipeline.collision.test_robot import RADIUS_M, link_middles, planar_spec
from tests.support.app import PLANAR3R_DIR, make_client

OBSTACLE_CENTRE = [0.0, 0.62, 0.0]  # on the path of link 2's middle
OBSTACLE = {"shape": "sphere", "dimensions": [0.15], "position": OBSTACLE_CENTRE}
BODY = {"robot": "planar3r", "task": "position", "target": {"position": [1.2, 0.9]}, "seed": 3}


@pytest.fixture(scope="module")
def with_geometry(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    models = tmp_path_factory.mktemp("models")
    model_dir = models / PLANAR3R_DIR.name
    shutil.copytree(PLANAR3R_DIR, model_dir)
    shutil.copytree(PLANAR3R_DIR.parent / "robots", models / "robots")
    (model_dir / COLLISION_FILE).write_text(planar_spec().model_dump_json())
    manifest = json.loads((model_dir / MANIFEST_FILE).read_text())
    manifest["files"][COLLISION_FILE] = sha256_of(model_dir / COLLISION_FILE)
    (model_dir / MANIFEST_FILE).write_text(json.dumps(manifest))
    with make_client(models) as client:
        yield client


def test_answers_are_clear_of_the_scene(with_geometry: TestClient) -> None:
    margin_m = 0.02
    body = {**BODY, "obstacles": [OBSTACLE], "collision": {"self": False, "margin_m": margin_m}}
    response = with_geometry.post("/smm", json=body)
    assert response.status_code == 200, response.text
    answer = response.json()
    assert answer["collision"] == {"self_checked": False, "obstacles": 1, "margin_m": margin_m}
    counts = answer["counts"]
    assert counts["rejected_collision"] > 0
    assert counts["sampled"] == sum(
        counts[k]
        for k in ("accepted", "rejected_tolerance", "rejected_joint_limits", "rejected_collision")
    )
    centre = np.asarray(OBSTACLE_CENTRE[:2])
    for component in answer["components"]:
        q = np.asarray(component["path"] + component["configurations"])
        clearance = np.linalg.norm(link_middles(q) - centre, axis=2) - 0.15 - RADIUS_M
        assert clearance.min() >= margin_m - 1e-12
        assert component["clearance_m"] == pytest.approx(clearance.min(), abs=1e-12)
        assert len(component["safest_configuration"]) == 3
    assert any("collision" in (c["ends"] or []) for c in answer["components"])
    robots = with_geometry.get("/robots").json()["models"]
    assert [m["collision_geometry"] for m in robots] == [True]


def test_a_batch_shares_one_scene(with_geometry: TestClient) -> None:
    body = {
        "robot": "planar3r", "task": "position", "seed": 3, "obstacles": [OBSTACLE],
        "targets": [{"target": {"position": [1.2, 0.9]}}, {"target": {"position": [1.0, 1.2]}}],
    }  # fmt: skip
    batch = with_geometry.post("/smm/batch", json=body).json()
    single = with_geometry.post("/smm", json={**BODY, "obstacles": [OBSTACLE]}).json()
    first = batch["results"][0]["answer"]
    assert first["components"] == single["components"]
    assert all(r["answer"]["collision"]["obstacles"] == 1 for r in batch["results"])


@pytest.mark.parametrize(
    ("change", "location"),
    [
        ({"obstacles": [{**OBSTACLE, "shape": "cone"}]}, ["body", "obstacles", 0, "shape"]),
        (
            {"obstacles": [OBSTACLE, {**OBSTACLE, "shape": "box"}]},
            ["body", "obstacles", 1, "dimensions"],
        ),
        (
            {"obstacles": [{**OBSTACLE, "dimensions": [0.0]}]},
            ["body", "obstacles", 0, "dimensions"],
        ),
        ({"obstacles": [{**OBSTACLE, "position": [0, 0]}]}, ["body", "obstacles", 0, "position"]),
        (
            {"obstacles": [{**OBSTACLE, "orientation": {"w": 0.5, "x": 0, "y": 0, "z": 0}}]},
            ["body", "obstacles", 0, "orientation"],
        ),
        ({"obstacles": [OBSTACLE] * (MAX_OBSTACLES + 1)}, ["body", "obstacles"]),
        ({"collision": {"margin_m": -0.1}}, ["body", "collision", "margin_m"]),
        ({"collision": {"self": "yes"}}, ["body", "collision", "self"]),
        ({"collision": {"selff": True}}, ["body", "collision", "selff"]),
    ],
)
def test_bad_scenes_get_a_422_naming_the_field(
    with_geometry: TestClient, change: dict[str, object], location: list[object]
) -> None:
    response = with_geometry.post("/smm", json={**BODY, **change})
    assert response.status_code == 422, response.text
    assert [e["loc"][: len(location)] for e in response.json()["detail"]] == [location]


def test_obstacles_need_a_model_with_collision_geometry(client: TestClient) -> None:
    response = client.post("/smm", json={**BODY, "obstacles": [OBSTACLE]})
    assert response.status_code == 422
    (error,) = response.json()["detail"]
    assert error["loc"] == ["body", "obstacles"]
    assert error["msg"].startswith("obstacles cannot be checked")
    assert "no collision geometry" in error["msg"]
    plain = client.post("/smm", json=BODY).json()
    assert plain["collision"]["self_checked"] is False
