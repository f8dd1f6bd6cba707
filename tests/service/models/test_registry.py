"""registry: models are verified by sha256 at start-up; a broken one is named and not served.

The app still starts and serves the models that verify, but /readyz answers 503 and
names the broken model and its file, and a request for that model gets 503 saying why.
A model that lists chain.json is served by the numpy chain kernel, checked against its
kinematics.onnx at load: a chain.json whose sha256 differs, whose joints are not the
model's, or whose kinematics disagree with kinematics.onnx (sha256 rewritten to match)
is refused naming the file and the difference. A model without chain.json (exported
before it existed) is still served, by kinematics.onnx.
"""

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from service.errors import ModelUnavailableError, ModelVerificationError, UnknownModelError
from service.manifest import CHAIN_FILE, MANIFEST_FILE, REPO_MODELS_DIR
from service.models.chain import SerialChainKinematics
from service.models.registry import Registry, load_model
from service.models.sessions import OnnxKinematics
from tests.support.app import PLANAR3R_DIR, make_client
from tests.support.chains import assert_chain_equals_onnx, model_without_chain


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
        registry.get("ur10", "position")
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


def rewrite_chain(model_dir: Path, edit: object) -> None:
    """Apply `edit` to chain.json's dict and record the new sha256 in the manifest."""
    chain = json.loads((model_dir / CHAIN_FILE).read_text())
    edit(chain)  # type: ignore[operator]
    (model_dir / CHAIN_FILE).write_text(json.dumps(chain))
    manifest = json.loads((model_dir / MANIFEST_FILE).read_text())
    manifest["files"][CHAIN_FILE] = hashlib.sha256(
        (model_dir / CHAIN_FILE).read_bytes()
    ).hexdigest()
    (model_dir / MANIFEST_FILE).write_text(json.dumps(manifest))


@pytest.mark.parametrize("model_id", ["planar3r-position", "iiwa14-pose", "iiwa14-position"])
def test_bundled_models_are_served_by_their_chain_equal_to_kinematics_onnx(model_id: str) -> None:
    model = load_model(REPO_MODELS_DIR / model_id, threads=1)
    assert CHAIN_FILE in model.manifest.files
    assert isinstance(model.kinematics, SerialChainKinematics)
    limits = model.limits
    q = np.random.default_rng(5).uniform(
        limits.lower_rad, limits.upper_rad, (1000, len(limits.lower_rad))
    )
    assert_chain_equals_onnx(model.kinematics, REPO_MODELS_DIR / model_id, q)


def test_tampered_chain_is_refused_naming_the_file(tmp_path: Path) -> None:
    models = copy_models(tmp_path)
    chain = models / PLANAR3R_DIR.name / CHAIN_FILE
    chain.write_text(chain.read_text().replace("1.0", "1.1", 1))
    with pytest.raises(ModelVerificationError, match=r"chain\.json: sha256 .* does not match"):
        load_model(models / PLANAR3R_DIR.name, threads=1)


def test_chain_that_disagrees_with_kinematics_onnx_is_refused(tmp_path: Path) -> None:
    models = copy_models(tmp_path)
    model_dir = models / PLANAR3R_DIR.name
    # The second link 1 mm longer: a valid chain, sha256 recorded, but not the exported arm.
    rewrite_chain(model_dir, lambda c: c["joints"][2]["origin"][0].__setitem__(3, 1.001))
    with pytest.raises(
        ModelVerificationError,
        match=r"planar3r-position/chain\.json: differs from kinematics\.onnx by 0\.001 ",
    ):
        load_model(model_dir, threads=1)
    registry = Registry.load(models)
    (failure,) = registry.failed
    assert failure.reason.startswith("planar3r-position/chain.json: differs from kinematics.onnx")


def test_chain_with_other_joints_is_refused(tmp_path: Path) -> None:
    models = copy_models(tmp_path)
    model_dir = models / PLANAR3R_DIR.name
    rewrite_chain(model_dir, lambda c: c["joints"][0].update(name="shoulder"))
    with pytest.raises(ModelVerificationError, match=r"chain\.json: joints \['shoulder'"):
        load_model(model_dir, threads=1)


def test_model_without_chain_is_served_by_kinematics_onnx(tmp_path: Path) -> None:
    model_dir = model_without_chain(tmp_path)
    models = model_dir.parent
    model = load_model(model_dir, threads=1)
    assert isinstance(model.kinematics, OnnxKinematics)
    body = {"robot": "planar3r", "task": "position", "target": {"position": [1.2, 0.4]}}
    with make_client(models) as client:
        assert client.get("/readyz").status_code == 200
        assert client.post("/smm", json={**body, "num_samples": 200}).status_code == 200
