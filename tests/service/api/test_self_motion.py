"""POST /smm/self-motion over HTTP, every path checked by an independent FK.

r = 4 (iiwa14 position): start and goal joined by a known self-motion (a null-space walk of
radians) get status ok and a path whose every point reaches the target within 1e-6 m by the
DH table, lies inside the limits, is at most 0.05 rad from the next, and whose ends are the
start and the goal; max_limit_margin ends at the best margin of the returned roadmap's nodes
(by the reference limits); two configurations on the elbow-up and elbow-down components are
not_connected, and a route over a roadmap edge that joins them finds no walk (no_path).
r = 1 (planar 3R): the path runs along the closed-form loop. Bad bodies get 422 naming the
field.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.connect import planner_settings
from service.pipeline.deadline import NO_DEADLINE
from service.pipeline.run import encode, space_of
from service.pipeline.self_motion import _roadmap_path
from service.pipeline.types import Query
from training.evaluate.references.iiwa14 import LIMITS_RAD
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.references.planar3r import closed_form_smm, planar3r_position
from training.evaluate.walks import null_space_walk

SPACING_RAD = 0.05


@pytest.fixture(scope="module")
def iiwa14_position() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-position", threads=1)


def motion(client: TestClient, robot: str, task: str, position: list[float], **body: Any) -> Any:
    response = client.post(
        "/smm/self-motion",
        json={"robot": robot, "task": task, "target": {"position": position}, **body},
    )
    return response


def check_path(path: np.ndarray, goal_m: np.ndarray) -> None:
    reached = iiwa14_pose(path)[:, :3, 3]
    assert np.linalg.norm(reached - goal_m, axis=1).max() <= 1e-6
    assert np.all(np.abs(path) <= LIMITS_RAD)
    assert np.linalg.norm(np.diff(path, axis=0), axis=1).max() <= SPACING_RAD


def test_a_known_self_motion_comes_back_as_an_exact_path(
    client: TestClient, iiwa14_position: ServedModel
) -> None:
    rng = np.random.default_rng(4)
    for seed in range(4):
        walk = np.zeros((1, 7))
        while np.linalg.norm(walk[-1] - walk[0]) < 1.0:  # a walk that leaves its start
            q0 = rng.uniform(-0.8 * LIMITS_RAD, 0.8 * LIMITS_RAD)
            walk = null_space_walk(iiwa14_position, q0, steps=80, seed=seed)
        goal_m = iiwa14_pose(q0[None])[0, :3, 3]
        body = {"start": walk[0].tolist(), "goal": {"configuration": walk[-1].tolist()}}
        answer = motion(client, "iiwa14", "position", goal_m.tolist(), seed=seed, **body).json()
        assert answer["status"] == "ok", answer
        path = np.array(answer["path"])
        check_path(path, goal_m)
        assert np.abs(path[0] - walk[0]).max() <= 1e-6 and np.abs(path[-1] - walk[-1]).max() <= 1e-6
        steps = np.linalg.norm(np.diff(path, axis=0), axis=1)
        assert answer["length_rad"] == pytest.approx(steps.sum())
        assert answer["start_component"] == answer["goal_component"]


def test_max_limit_margin_ends_at_the_best_node_of_the_roadmap(
    client: TestClient, iiwa14_position: ServedModel
) -> None:
    q0 = np.array([0.3, 0.5, -0.4, -1.3, 0.6, 0.9, 0.2])
    goal_m = iiwa14_pose(q0[None])[0, :3, 3]
    body = {"start": q0.tolist(), "goal": {"objective": "max_limit_margin"}}
    answer = motion(client, "iiwa14", "position", goal_m.tolist(), **body).json()
    assert answer["status"] == "ok"
    path = np.array(answer["path"])
    check_path(path, goal_m)

    def margin(q: np.ndarray) -> np.ndarray:
        return np.min(LIMITS_RAD - np.abs(q), axis=-1)  # the reference's symmetric limits

    nodes = np.array(answer["roadmap"]["nodes"])
    assert margin(path[-1]) >= margin(nodes).max() - 1e-12
    assert answer["objective_value"] == pytest.approx(margin(path[-1]), abs=1e-12)
    assert margin(path[-1]) >= margin(q0)  # the start is a node too


# The end effector is kept 0.82 +- 0.126 m from the shoulder with the elbow straight,
# farther than this target's 0.674 m: the elbow's sign (q4) parts the components.
ELBOW_TARGET_M = [0.544, 0.136, 0.734]


def elbow_up_and_down(client: TestClient) -> tuple[list[float], list[float]]:
    """A component representative with q4 > 0 and one with q4 < 0 at ELBOW_TARGET_M."""
    listed = client.post(
        "/smm",
        json={"robot": "iiwa14", "task": "position", "target": {"position": ELBOW_TARGET_M}},
    ).json()["components"]
    up = next(c["representative"] for c in listed if c["representative"][3] > 0)
    down = next(c["representative"] for c in listed if c["representative"][3] < 0)
    return up, down


def test_start_and_goal_on_elbow_up_and_down_are_not_connected(client: TestClient) -> None:
    position = ELBOW_TARGET_M
    up, down = elbow_up_and_down(client)
    body = {"start": up, "goal": {"configuration": down}}
    answer = motion(client, "iiwa14", "position", position, **body).json()
    assert answer["status"] == "not_connected" and answer["path"] is None
    assert answer["start_component"] != answer["goal_component"]
    components = answer["components"]
    assert components[answer["start_component"]]["representative"][3] > 0
    assert components[answer["goal_component"]]["representative"][3] < 0


def test_a_roadmap_edge_no_fine_walk_follows_gives_no_route(
    client: TestClient, iiwa14_position: ServedModel
) -> None:
    """The route search over a roadmap (`_roadmap_path`) whose one edge joins the elbow-up
    and elbow-down components (which no motion on the fibre joins: the elbow's sign parts
    them) finds no walkable route and says so (None, answered as `no_path`), not an error."""
    position = ELBOW_TARGET_M
    up, down = elbow_up_and_down(client)
    model = iiwa14_position
    query = Query.for_model(model.manifest, position_m=position)
    space = space_of(model, encode(model, query), query.tolerance, CollisionCheck.none())
    planner = planner_settings(model.manifest.defaults.connectivity)
    nodes, edges = np.array([up, down]), np.array([[0, 1]])
    assert _roadmap_path(space, nodes, edges, 0, 1, planner, NO_DEADLINE) is None


def test_planar_self_motion_runs_along_the_closed_form_loop(client: TestClient) -> None:
    target = np.array([0.5, 0.0])
    loop = closed_form_smm(target, 0.01)[0]  # (K, 3) one exact loop, in phi order
    start, goal = loop[10], loop[300]
    body = {"start": start.tolist(), "goal": {"configuration": goal.tolist()}}
    answer = motion(client, "planar3r", "position", target.tolist(), **body).json()
    assert answer["status"] == "ok" and answer["roadmap"] is None
    path = np.array(answer["path"])
    assert np.abs(planar3r_position(path) - target).max() <= 1e-6
    steps = np.linalg.norm(np.angle(np.exp(1j * np.diff(path, axis=0))), axis=1)
    assert steps.max() <= SPACING_RAD
    gap = np.angle(np.exp(1j * (path[[0, -1]] - np.stack([start, goal]))))
    assert np.abs(gap).max() <= 1e-6


@pytest.mark.parametrize(
    ("body", "field", "words"),
    [
        ({"start": [0.0] * 7, "goal": {"objective": "max_limit_margin"}}, "start", "within 0.1"),
        ({"start": [0.1] * 6, "goal": {"objective": "max_limit_margin"}}, "start", "7 values"),
        ({"start": [0.1] * 7, "goal": {}}, "goal", "exactly one"),
        (
            {"start": [0.1] * 7, "goal": {"objective": "max_limit_margin", "nearest_to": [0] * 7}},
            "goal",
            "exactly one",
        ),
        ({"start": [0.1] * 7, "goal": {"nearest_to": [0.0] * 3}}, "goal.nearest_to", "7 values"),
        ({"start": [0.1] * 7, "goal": {"objective": "closest"}}, "goal.objective", ""),
    ],
)
def test_bad_bodies_get_422_naming_the_field(
    client: TestClient, body: dict[str, Any], field: str, words: str
) -> None:
    response = motion(client, "iiwa14", "position", [0.5, 0.0, 0.6], **body)
    assert response.status_code == 422, response.text
    detail = response.json()["detail"]
    assert any(".".join(str(x) for x in d["loc"][1:]) == field for d in detail), detail
    assert any(words in d["msg"] for d in detail)


def test_objectives_an_arm_cannot_have_are_refused(client: TestClient) -> None:
    start = closed_form_smm(np.array([0.5, 0.0]))[0][0].tolist()
    margin = motion(
        client, "planar3r", "position", [0.5, 0.0], start=start,
        goal={"objective": "max_limit_margin"},
    )  # fmt: skip
    assert margin.status_code == 422 and "no joint limits" in margin.text
    q0 = [0.3, 0.5, -0.4, -1.3, 0.6, 0.9, 0.2]
    goal_m = iiwa14_pose(np.array(q0)[None])[0, :3, 3].tolist()
    clearance = motion(
        client, "iiwa14", "position", goal_m, start=q0, goal={"objective": "max_clearance"},
        collision={"self": False},
    )  # fmt: skip
    assert clearance.status_code == 422 and "collisions checked" in clearance.text
