"""POST /smm for the iiwa14 pose (r=1) and position (r=4) models, over HTTP.

Every returned configuration is re-checked with the references' DH forward kinematics
(training/evaluate/references/iiwa14.py): it must reach the target within the tolerance
and lie within the paper's joint limits, and every sample must be accounted for. Shape
errors name the field; an unreachable target is `no_solution`, a target at the arm's full
reach is answered; components are ordered by
their distance to a reference configuration, each reporting its nearest member; an r = 4
component's roadmap is a connected graph of exact nodes.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial.transform import Rotation

from tests.support.bundled import default_num_samples
from training.evaluate.references.iiwa14 import LIMITS_RAD
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.evaluate.references.rotations import rotation_angle_rad

TASKS = ("pose", "position")


def target_of(q_rad: np.ndarray, task: str) -> dict[str, Any]:
    pose = iiwa14_pose(q_rad)[0]
    target: dict[str, Any] = {"position": pose[:3, 3].tolist()}
    if task == "pose":
        x, y, z, w = Rotation.from_matrix(pose[:3, :3]).as_quat()
        target["orientation"] = {"w": w, "x": x, "y": y, "z": z}
    return target


def held_out(count: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-LIMITS_RAD, LIMITS_RAD, (count, 7))


def smm(client: TestClient, task: str, target: dict[str, Any], **options: Any) -> Any:
    return client.post("/smm", json={"robot": "iiwa14", "task": task, "target": target, **options})


def configurations(answer: dict[str, Any]) -> np.ndarray:
    return np.array([q for c in answer["components"] for q in c["configurations"]]).reshape(-1, 7)


@pytest.mark.parametrize("task", TASKS)
def test_every_configuration_reaches_the_target_within_the_limits(
    client: TestClient, task: str
) -> None:
    for i, q_target in enumerate(held_out(3, seed=11)):
        response = smm(client, task, target_of(q_target[None], task), seed=i)
        assert response.status_code == 200, response.text
        answer = response.json()
        assert answer["status"] == "ok"
        assert answer["redundancy"] == (1 if task == "pose" else 4)
        assert answer["model"].startswith(f"iiwa14-{task}@")
        q = configurations(answer)
        reached = iiwa14_pose(q)
        goal = iiwa14_pose(q_target[None])[0]
        assert np.linalg.norm(reached[:, :3, 3] - goal[:3, 3], axis=1).max() <= 1e-6
        if task == "pose":
            goal_rotation = np.broadcast_to(goal[:3, :3], (len(q), 3, 3))
            assert rotation_angle_rad(reached[:, :3, :3], goal_rotation).max() <= 1e-6
        assert np.all(np.abs(q) <= LIMITS_RAD)
        counts = answer["counts"]
        default = default_num_samples(f"iiwa14-{task}")
        assert counts["sampled"] == default
        outcomes = ("accepted", "rejected_tolerance", "rejected_joint_limits")
        assert sum(counts[k] for k in outcomes) == default
        assert sum(c["size"] for c in answer["components"]) == counts["accepted"] == len(q)


def test_position_task_ignores_orientation_of_the_answers(client: TestClient) -> None:
    """r = 4: the answers to a position target span many end-effector orientations."""
    q_target = held_out(1, seed=12)
    q = configurations(smm(client, "position", target_of(q_target, "position")).json())
    rotations = iiwa14_pose(q)[:, :3, :3]
    spread = rotation_angle_rad(rotations, np.broadcast_to(rotations[0], rotations.shape))
    assert spread.max() > 1.0


def test_orientation_on_a_position_task_is_refused(client: TestClient) -> None:
    target = target_of(held_out(1, seed=13), "pose")
    response = smm(client, "position", target)
    assert response.status_code == 422
    assert response.json()["detail"][0]["loc"] == ["body", "target", "orientation"]
    assert "pose" in response.json()["detail"][0]["msg"]


def test_missing_orientation_on_a_pose_task_is_refused(client: TestClient) -> None:
    response = smm(client, "pose", target_of(held_out(1, seed=14), "position"))
    assert response.status_code == 422
    assert response.json()["detail"][0]["loc"] == ["body", "target", "orientation"]


@pytest.mark.parametrize("task", TASKS)
def test_wrong_position_length_names_the_field(client: TestClient, task: str) -> None:
    target = target_of(held_out(1, seed=15), task)
    target["position"] = target["position"][:2]
    response = smm(client, task, target)
    assert response.status_code == 422
    assert response.json()["detail"][0]["loc"] == ["body", "target", "position"]
    assert "3 values" in response.json()["detail"][0]["msg"]


@pytest.mark.parametrize("task", TASKS)
def test_a_target_two_metres_away_has_no_solution(client: TestClient, task: str) -> None:
    target = target_of(held_out(1, seed=16), task)
    target["position"] = [2.0, 0.0, 0.36]  # 2 m from the shoulder; reach is ~1.2 m
    response = smm(client, task, target)
    assert response.status_code == 200
    answer = response.json()
    assert answer["status"] == "no_solution" and answer["components"] == []
    assert answer["counts"]["accepted"] == 0


def test_a_target_at_full_reach_is_answered_not_called_unreachable(client: TestClient) -> None:
    """The arm stretched out (elbow and wrist straight): reachable, at a fold of the
    position map where the served DLS steps end micrometres short for every sample."""
    q_target = np.array([[0.3, 0.2, 0.1, 0.0, 0.2, 0.0, 0.0]])
    response = smm(client, "position", target_of(q_target, "position"))
    assert response.status_code == 200, response.text
    answer = response.json()
    assert answer["status"] == "ok" and answer["counts"]["accepted"] > 0
    q = configurations(answer)
    goal = iiwa14_pose(q_target)[0][:3, 3]
    assert np.linalg.norm(iiwa14_pose(q)[:, :3, 3] - goal, axis=1).max() <= 1e-6
    assert np.all(np.abs(q) <= LIMITS_RAD)


@pytest.mark.parametrize("task", TASKS)
def test_components_are_ordered_by_distance_to_the_reference(client: TestClient, task: str) -> None:
    q_target = held_out(1, seed=17)
    reference = np.zeros(7)
    answer = smm(
        client, task, target_of(q_target, task), reference_configuration=reference.tolist()
    ).json()
    components = answer["components"]
    assert components
    distances = [c["distance_to_reference"] for c in components]
    assert distances == sorted(distances)
    for component in components:
        # The nearest point of the component: among its members and its path (pose, r = 1).
        members = np.array(component["configurations"] + (component["path"] or []))
        member_distances = np.linalg.norm(members - reference, axis=1)  # no periodic joints
        nearest = members[np.argmin(member_distances)]
        np.testing.assert_allclose(component["nearest_to_reference"], nearest)
        assert component["distance_to_reference"] == pytest.approx(member_distances.min())


def test_robots_lists_both_iiwa_tasks(client: TestClient) -> None:
    models = {(m["robot"], m["task"]) for m in client.get("/robots").json()["models"]}
    assert {("iiwa14", "pose"), ("iiwa14", "position")} <= models


def test_include_roadmap_gives_each_r4_component_a_connected_graph_of_exact_nodes(
    client: TestClient,
) -> None:
    """Position task (r = 4), include_roadmap: each component's roadmap starts with its
    members in the order of `configurations`; every node reaches the target within 1e-6 m
    by the DH table and lies inside the limits; the edges are distinct pairs i < j that
    join every node (scipy's connected components: one). The same request without it
    has no roadmaps and the same components. A pose answer (r = 1, traced) has none."""
    for i, q_target in enumerate(held_out(3, seed=23)):
        target = target_of(q_target[None], "position")
        answer = smm(client, "position", target, seed=i, include_roadmap=True).json()
        plain = smm(client, "position", target, seed=i).json()
        assert [c["configurations"] for c in answer["components"]] == [
            c["configurations"] for c in plain["components"]
        ]
        assert all(c["roadmap"] is None for c in plain["components"])
        goal = iiwa14_pose(q_target[None])[0, :3, 3]
        for component in answer["components"]:
            nodes = np.array(component["roadmap"]["nodes"])
            edges = np.array(component["roadmap"]["edges"], dtype=np.int64).reshape(-1, 2)
            assert nodes[: component["size"]].tolist() == component["configurations"]
            reached = iiwa14_pose(nodes)[:, :3, 3]
            assert np.linalg.norm(reached - goal, axis=1).max() <= 1e-6
            assert np.all(np.abs(nodes) <= LIMITS_RAD)
            assert np.all(edges[:, 0] < edges[:, 1]) and edges.max(initial=0) < len(nodes)
            assert len(np.unique(edges, axis=0)) == len(edges)
            graph = coo_matrix(
                (np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(nodes),) * 2
            )
            assert connected_components(graph, directed=False)[0] == 1
    pose = smm(client, "pose", target_of(held_out(1, seed=5), "pose"), include_roadmap=True)
    assert all(c["roadmap"] is None for c in pose.json()["components"])
