"""registry: models are verified by sha256 at start-up; a broken one stops start-up by name."""

import shutil
from pathlib import Path

import pytest

from service.config import REPO_MODELS_DIR
from service.errors import ModelVerificationError, UnknownModelError
from service.registry import Registry, load_model
from tests.conftest import PLANAR3R_DIR, make_client


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
    # The app refuses to start at all.
    with pytest.raises(ModelVerificationError, match=r"flow\.onnx"), make_client(models):
        pass


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
