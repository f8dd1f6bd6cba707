"""POST /smm for the Franka Panda pose model (r = 1), over HTTP, against exact truth.

The Panda is served from its robot file and URDF alone (models/robots/panda.*). Every
returned configuration, samples and path points, is re-checked by the references' float64
URDF chain (training/evaluate/references/urdf_chain.py, not pytorch-kinematics): it
reaches the target within the tolerance and lies inside the Panda's own limits (q4 and q6
not symmetric).
Against the exact SMM (eaik's 6R IK over a q7 sweep, training/evaluate/references/panda.py)
every component of 0.5 rad or more holds a returned configuration within 0.05 rad.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from fastapi.testclient import TestClient
from scipy.spatial.transform import Rotation

from service.manifest import REPO_MODELS_DIR
from training.evaluate.references.panda import pose_smm
from training.evaluate.references.urdf_chain import read_chain

CHAIN = read_chain(REPO_MODELS_DIR / "robots" / "panda.urdf", "panda_hand_tcp", "panda_link0")
TOLERANCE = 1e-6


def _rotation_angle_rad(r_a: np.ndarray, r_b: np.ndarray) -> np.ndarray:  # (B, 3, 3) -> (B,)
    return np.linalg.norm(Rotation.from_matrix(r_a @ np.swapaxes(r_b, -1, -2)).as_rotvec(), axis=1)


def _returned(answer: dict[str, Any]) -> np.ndarray:  # (P, 7) members and path points
    rows = [q for c in answer["components"] for q in c["configurations"] + (c["path"] or [])]
    return np.array(rows).reshape(-1, 7)


def test_panda_pose_answers_are_exact_inside_its_limits_and_find_every_long_component(
    client: TestClient,
) -> None:
    rng = np.random.default_rng(2026)
    for i in range(3):
        q_target = rng.uniform(CHAIN.lower, CHAIN.upper)
        goal = CHAIN.pose(q_target[None])[0]  # (4, 4)
        x, y, z, w = Rotation.from_matrix(goal[:3, :3]).as_quat()
        target = {"position": goal[:3, 3].tolist(), "orientation": {"w": w, "x": x, "y": y, "z": z}}
        body = {"robot": "panda", "task": "pose", "target": target, "num_samples": 1000, "seed": i}
        response = client.post("/smm", json=body)
        assert response.status_code == 200, response.text
        answer = response.json()
        assert answer["status"] == "ok" and answer["model"].startswith("panda-pose@")
        q = _returned(answer)
        reached = CHAIN.pose(q)  # (P, 4, 4)
        assert np.linalg.norm(reached[:, :3, 3] - goal[:3, 3], axis=1).max() <= TOLERANCE
        assert _rotation_angle_rad(reached[:, :3, :3], goal[None, :3, :3]).max() <= TOLERANCE
        assert np.all((q >= CHAIN.lower) & (q <= CHAIN.upper))

        for component in pose_smm(goal[:3, 3], goal[:3, :3]):
            if component.arc_length_rad < 0.5:
                continue
            gaps = np.linalg.norm(component.q_rad[:, None, :] - q[None, :, :], axis=2)  # (K, P)
            assert gaps.min() <= 0.05, f"target {i}: a {component.arc_length_rad:.2f} rad miss"
