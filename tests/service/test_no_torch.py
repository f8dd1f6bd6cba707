"""The service answers a request without importing torch, pytorch-kinematics or coal (the
training's collision reference: the service checks collision.json's spheres in numpy)."""

import subprocess
import sys

SCRIPT = """
import sys
from fastapi.testclient import TestClient
from service.main import create_app
with TestClient(create_app()) as client:
    body = {"robot": "planar3r", "task": "position", "target": {"position": [0.5, 0.0]}}
    assert client.post("/smm", json=body).status_code == 200
TRAINING_ONLY = ("torch", "pytorch_kinematics", "coal")
leaked = sorted(m for m in sys.modules if m.split(".")[0] in TRAINING_ONLY)
print(leaked)
sys.exit(1 if leaked else 0)
"""


def test_service_does_not_import_torch() -> None:
    result = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
