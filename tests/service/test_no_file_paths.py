"""No request field ever becomes a file path: after start-up the service reads no files.

The app is started on a copy of the models, the copy is deleted, and the app still
answers every model; path-like robot and task names are unknown names (404).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from service.manifest import REPO_MODELS_DIR
from tests.support.app import make_client


def test_requests_are_answered_from_memory_only(tmp_path: Path) -> None:
    models = tmp_path / "models"
    shutil.copytree(REPO_MODELS_DIR, models)
    with make_client(models) as client:
        shutil.rmtree(models)
        for robot, task, position in (
            ("planar3r", "position", [0.5, 0.0]),
            ("iiwa14", "position", [0.5, 0.0, 0.6]),
        ):
            body = {
                "robot": robot,
                "task": task,
                "target": {"position": position},
                "num_samples": 50,
            }
            assert client.post("/smm", json=body).status_code == 200
        for robot, task in (
            ("../robots", "position"),
            ("/etc/passwd", "position"),
            ("planar3r", "../../manifest.json"),
            ("planar3r-position/flow.onnx", "position"),
        ):
            body = {"robot": robot, "task": task, "target": {"position": [0.5, 0.0]}}
            response = client.post("/smm", json=body)
            assert response.status_code == 404
            assert "served" in response.json()["detail"]
