"""registry: models are verified by sha256 at start-up; a broken one is named and not served.

The app still starts and serves the models that verify, but /readyz answers 503 and
names the broken model and its file, and a request for that model gets 503 saying why.
"""

import shutil
from pathlib import Path

import pytest

from service.errors import ModelUnavailableError, ModelVerificationError, UnknownModelError
from service.manifest import REPO_MODELS_DIR
from service.models.registry import Registry, load_model
from tests.support.app import PLANAR3R_DIR, make_client


def copy_models(tmp_path: Path) -> Path:
    models = tmp_path / "models"
    shutil.copytree(REPO_MODELS_DIR / "robots", models / "robots")
    shutil.copytree(PLANAR3R_DIR, models / PLANAR3R_DIR.name)
    return models


def test_bundled_models_verify_and_are_keyed_by_robot_and_task() -> None:
    registry = Registry.load(REPO_MODELS_DIR)
    model = registry.get("planar3r", "position")
    assert model.reference.startswith("planar3r-position@") and len(model.version) == 12
    with pytest.raises(UnknownModelError, match=r"served robots: .*planar3r"):
        registry.get("ur5", "position")
    with pytest.raises(UnknownModelError, match="served tasks: position"):
        registry.get("planar3r", "pose")


def test_tampered_flow_is_refused_naming_the_file(tmp_path: Path) -> None:
    models = copy_models(tmp_path)
    flow = models / PLANAR3R_DIR.name / "flow.onnx"
    data = bytearray(flow.read_bytes())
    data[len(data) // 2] ^= 0xFF
    flow.write_bytes(bytes(data))
    with pytest.raises(ModelVerificationError, match=r"flow\.onnx: sha256 .* does not match"):
        load_model(models / PLANAR3R_DIR.name, threads=1)
    registry = Registry.load(models)
    assert registry.all() == [] and not registry.ready
    (failure,) = registry.failed
    assert failure.name == PLANAR3R_DIR.name and (failure.robot, failure.task) == (
        "planar3r",
        "position",
    )
    assert failure.reason.startswith(f"{PLANAR3R_DIR.name}/flow.onnx: sha256 ")
    with pytest.raises(ModelUnavailableError, match=r"failed verification .*/flow\.onnx"):
        registry.get("planar3r", "position")


def test_app_with_a_broken_model_serves_the_others_and_is_not_ready(tmp_path: Path) -> None:
    models = copy_models(tmp_path)
    shutil.copytree(REPO_MODELS_DIR / "iiwa14-position", models / "iiwa14-position")
    (models / PLANAR3R_DIR.name / "kinematics.onnx").write_bytes(b"not a model")
    body = {"robot": "iiwa14", "task": "position", "target": {"position": [0.5, 0.0, 0.6]}}
    with make_client(models) as client:
        assert client.get("/healthz").status_code == 200
        ready = client.get("/readyz")
        assert ready.status_code == 503
        assert ready.json()["status"] == "not_ready"
        assert [m.split("@")[0] for m in ready.json()["models"]] == ["iiwa14-position"]
        (failed,) = ready.json()["failed"]
        assert failed["name"] == "planar3r-position" and "kinematics.onnx" in failed["reason"]
        assert client.post("/smm", json={**body, "num_samples": 50}).status_code == 200
        refused = client.post(
            "/smm", json={"robot": "planar3r", "task": "position", "target": {"position": [1, 0]}}
        )
        assert refused.status_code == 503
        assert "planar3r-position" in refused.json()["detail"]
        assert "kinematics.onnx" in refused.json()["detail"]
        metrics = client.get("/metrics").text
        assert 'smm_model_ready{model="planar3r-position"} 0.0' in metrics
        assert 'smm_model_ready{model="iiwa14-position"} 1.0' in metrics


def test_missing_file_and_changed_urdf_are_refused(tmp_path: Path) -> None:
    models = copy_models(tmp_path)
    (models / PLANAR3R_DIR.name / "kinematics.onnx").unlink()
    with pytest.raises(ModelVerificationError, match=r"kinematics\.onnx: file listed .* missing"):
        load_model(models / PLANAR3R_DIR.name, threads=1)
    models = copy_models(tmp_path / "again")
    urdf = models / "robots" / "planar3r.urdf"
    urdf.write_text(urdf.read_text().replace('xyz="1 0 0"', 'xyz="1.1 0 0"', 1))
    with pytest.raises(ModelVerificationError, match=r"planar3r\.urdf: sha256"):
        load_model(models / PLANAR3R_DIR.name, threads=1)


def test_empty_models_directory_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ModelVerificationError, match=r"no \*/manifest\.json"):
        Registry.load(tmp_path)
