"""POST /smm and POST /smm/self-motion for the tool-axis task, over HTTP, against exact
truth.

The UR5 (example-robot-data's URDF, tool axis z of tool0: r = 1) and the iiwa14
(tool axis z of its flange: r = 2) serve `{"position": [..], "axis": [..]}`. Every returned
configuration, samples and path points, is re-checked by the references' float64 URDF chain
(training/evaluate/references/urdf_chain.py, not pytorch-kinematics): it reaches the target
position within 1e-6 m with the tool axis within 1e-6 rad of the target axis. On the UR5
every exact component (eaik's IK over psi, references/axis.py) holds a returned
configuration (self-collision off: the reference is kinematic). A self-motion path on the
iiwa14's 2-D SMM is exact point by point and at most 0.05 rad a step. A target without its
axis, with an orientation instead, or with a non-unit axis is a 422 naming the field.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi.testclient import TestClient

from service.manifest import REPO_MODELS_DIR
from service.pipeline.joint_space import JointBox
from training.evaluate.references.axis import ur5_axis_smm
from training.evaluate.references.urdf_chain import UrdfChain, read_chain

UR5 = read_chain(REPO_MODELS_DIR / "robots" / "ur5.urdf", "tool0", "base_link")
IIWA14 = read_chain(REPO_MODELS_DIR / "robots" / "iiwa14.urdf", "ee", "base_link")
TOLERANCE = 1e-6
Z = np.array([0.0, 0.0, 1.0])


def _returned(answer: dict[str, Any], n: int) -> np.ndarray:  # (P, n) members and path points
    rows = [q for c in answer["components"] for q in c["configurations"] + (c["path"] or [])]
    return np.array(rows).reshape(-1, n)


def _check_exact(chain: UrdfChain, q: np.ndarray, position: np.ndarray, axis: np.ndarray) -> None:
    reached = chain.pose(q)  # (P, 4, 4)
    assert np.linalg.norm(reached[:, :3, 3] - position, axis=1).max() <= TOLERANCE
    tool = reached[:, :3, :3] @ Z  # (P, 3)
    angle = np.arctan2(np.linalg.norm(np.cross(tool, axis), axis=1), tool @ axis)
    assert angle.max() <= TOLERANCE


def test_ur5_axis_answers_are_exact_and_find_every_exact_component(client: TestClient) -> None:
    rng = np.random.default_rng(2027)
    periodic = np.ones(6, bool)
    for i in range(3):
        q_target = rng.uniform(-np.pi, np.pi, 6)
        goal = UR5.pose(q_target[None])[0]
        target = {"position": goal[:3, 3].tolist(), "axis": goal[:3, 2].tolist()}
        # The kinematic fibre, as the reference traces it: self-collision not checked.
        body = {
            "robot": "ur5", "task": "axis", "target": target, "seed": i,
            "collision": {"self": False},
        }  # fmt: skip
        response = client.post("/smm", json=body)
        assert response.status_code == 200, response.text
        answer = response.json()
        assert answer["status"] == "ok" and answer["model"].startswith("ur5-axis@")
        q = _returned(answer, 6)
        _check_exact(UR5, q, goal[:3, 3], goal[:3, 2])
        exact = ur5_axis_smm(goal[:3, 3], goal[:3, 2], Z)
        box = JointBox.covering(np.concatenate([exact.q_rad, q]), periodic, margin_rad=10.0)
        nearest = box.tree(q).query(box.points(exact.q_rad))[0]  # (P_exact,)
        for c in range(exact.count):
            assert nearest[exact.component == c].min() <= 0.05, f"target {i}: missed {c}"
        assert len(answer["components"]) == exact.count


def test_iiwa14_axis_self_motion_path_is_exact_and_fine(client: TestClient) -> None:
    q_start = np.array([0.3, 0.6, -0.2, -1.2, 0.4, 0.9, 0.1])
    goal = IIWA14.pose(q_start[None])[0]
    target = {"position": goal[:3, 3].tolist(), "axis": goal[:3, 2].tolist()}
    body = {
        "robot": "iiwa14", "task": "axis", "target": target, "start": q_start.tolist(),
        "goal": {"objective": "max_limit_margin"},
    }  # fmt: skip
    response = client.post("/smm/self-motion", json=body)
    assert response.status_code == 200, response.text
    answer = response.json()
    assert answer["status"] == "ok"
    path = np.array(answer["path"])
    _check_exact(IIWA14, path, goal[:3, 3], goal[:3, 2])
    assert np.linalg.norm(np.diff(path, axis=0), axis=1).max() <= 0.05 + 1e-9
    assert np.linalg.norm(path[0] - q_start) <= 1e-6
    assert np.all((path >= IIWA14.lower) & (path <= IIWA14.upper))


def test_axis_targets_that_do_not_fit_the_task_name_the_field(client: TestClient) -> None:
    position = [0.4, 0.1, 0.5]
    cases = [
        ({"position": position}, "required for the axis task"),
        ({"position": position, "axis": [0.0, 0.0, 3.0]}, "must be a unit vector"),
        (
            {
                "position": position,
                "axis": [0, 0, 1.0],
                "orientation": {"w": 1, "x": 0, "y": 0, "z": 0},
            },
            "not allowed for the axis task",
        ),
    ]
    for target, message in cases:
        response = client.post("/smm", json={"robot": "ur5", "task": "axis", "target": target})
        assert response.status_code == 422, response.text
        assert message in response.text
    identity = {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0}
    pose_target = {"position": position, "orientation": identity, "axis": [0, 0, 1.0]}
    pose = client.post("/smm", json={"robot": "iiwa14", "task": "pose", "target": pose_target})
    assert pose.status_code == 422 and "target.axis is not allowed for the pose task" in pose.text
