"""smm-train end to end: a tiny model is trained, exported and served by the real service.

`--refresh-kinematics` re-exports only the kinematics of an existing model directory: it
gains chain.json, its flow is untouched, and the service serves it by the chain.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from service.manifest import CHAIN_FILE, Manifest
from service.models.chain import SerialChainKinematics
from service.models.registry import load_model, sha256_of
from tests.support.app import make_client
from tests.support.chains import model_without_chain
from training.cli import main
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
    assert sorted(manifest.files) == ["chain.json", "flow.onnx", "kinematics.onnx"]
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


def test_refresh_kinematics_flag_gives_an_existing_model_its_chain(tmp_path: Path) -> None:
    model_dir = model_without_chain(tmp_path)
    flow = sha256_of(model_dir / "flow.onnx")
    argv = ["--robot", "planar3r", "--task", "position", "--models-dir", str(model_dir.parent)]
    main([*argv, "--refresh-kinematics"])
    manifest = Manifest.model_validate_json((model_dir / "manifest.json").read_text())
    assert manifest.files[CHAIN_FILE] == sha256_of(model_dir / CHAIN_FILE)
    assert manifest.files["flow.onnx"] == flow
    assert isinstance(load_model(model_dir, threads=1).kinematics, SerialChainKinematics)
    with pytest.raises(SystemExit):  # it trains nothing, so it does not combine with --resume
        main([*argv, "--refresh-kinematics", "--resume"])
