"""smm-train end to end: a tiny model is trained, exported and served by the real service."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from service.manifest import Manifest
from service.models.registry import sha256_of
from tests.support.app import make_client
from training.evaluate.references.planar3r import planar3r_position


def test_tiny_model_trains_exports_and_is_served(tmp_path: Path) -> None:
    models, runs = tmp_path / "models", tmp_path / "runs"
    command = [
        sys.executable, "-m", "training.cli",
        "--robot", "planar3r", "--task", "position",
        "--samples", "4000", "--epochs", "2",
        "--eval-targets", "4", "--eval-samples-per-target", "200",
        "--models-dir", str(models), "--runs-dir", str(runs),
    ]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]

    model_dir = models / "planar3r-position"
    manifest = Manifest.model_validate_json((model_dir / "manifest.json").read_text())
    assert (manifest.training.samples, manifest.training.epochs) == (4000, 2)
    assert manifest.training.device == "cpu" and manifest.training.wall_time_s > 0
    assert manifest.training.command.startswith("smm-train --robot planar3r")
    assert np.isfinite(manifest.training.best_validation_loss)
    assert manifest.quality is not None and manifest.quality.held_out_targets == 4
    for name, digest in manifest.files.items():
        assert sha256_of(model_dir / name) == digest
    assert (runs / "planar3r-position" / "best.pt").is_file()
    assert len(json.loads((runs / "planar3r-position" / "history.json").read_text())) == 2

    with make_client(models) as client:
        target = [1.5, 0.5]
        body = {"robot": "planar3r", "task": "position", "target": {"position": target}}
        response = client.post("/smm", json={**body, "num_samples": 2000})
    assert response.status_code == 200
    answer = response.json()
    assert answer["model"].startswith("planar3r-position@")
    q = np.array([q for c in answer["components"] for q in c["configurations"]]).reshape(-1, 3)
    # Even a barely trained flow, once corrected, returns only exact configurations.
    assert np.all(np.linalg.norm(planar3r_position(q) - target, axis=1) <= 1e-6)
