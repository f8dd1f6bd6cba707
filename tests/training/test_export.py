"""export: parity with torch is checked for every exported file, and a mismatch fails loudly.

flow.onnx and kinematics.onnx against torch through onnxruntime; a flow's outputs within
1e-4 + 1e-5 x the largest |output| of their row (worked by hand: rounding of a row in
the thousands passes at an output of about 1, the same error in a row of ones fails);
chain.json through the service's numpy kernel against pytorch-kinematics (1e-12), for
the planar 3R and for a URDF with fixed joints, oblique axes and a continuous joint.
`refresh_kinematics` writes kinematics.onnx and chain.json into an existing model
directory (the flow, and the manifest but for its `files` digests, untouched) and the
registry then serves the chain, equal to kinematics.onnx; it refuses a URDF that is not
the one the model was trained on and leaves the directory as it was. It rebuilds the
chain from the base link chain.json records, not from the URDF's root, when the URDF has
links above it.
"""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from service.manifest import (
    CHAIN_FILE,
    FLOW_FILE,
    MANIFEST_FILE,
    REPO_MODELS_DIR,
    ChainSpec,
)
from service.models.chain import SerialChainKinematics
from service.models.registry import load_model, sha256_of
from service.models.sessions import OnnxKinematics
from tests.support.app import PLANAR3R_DIR
from tests.support.chains import (
    TWISTED_END_EFFECTOR,
    assert_chain_equals_onnx,
    model_without_chain,
    write_twisted_urdf,
)
from training.export import (
    ExportParityError,
    check_chain_parity,
    check_flow_parity,
    check_kinematics_parity,
    export_chain,
    export_flow,
    export_kinematics,
    flow_parity_excess,
    refresh_kinematics,
)
from training.kinematics import ForwardKinematics, joint_spec, load_chain
from training.model import VelocityField

URDF = REPO_MODELS_DIR / "robots" / "planar3r.urdf"


def test_flow_export_reproduces_torch_and_refuses_another_network(tmp_path: Path) -> None:
    torch.manual_seed(0)
    exported, other = VelocityField(3, 2, 32, 2), VelocityField(3, 2, 32, 2)
    path = tmp_path / "flow.onnx"
    export_flow(exported, path, joint_dim=3, condition_dim=2)  # checks parity itself
    check_flow_parity(exported, path, 3, 2)
    with pytest.raises(ExportParityError, match=r"flow\.onnx: flow differs from torch"):
        check_flow_parity(other, path, 3, 2)


def test_flow_parity_is_bounded_at_each_rows_scale() -> None:
    expected = np.array([[2500.0, 2.0, -1.0], [1.0, 2.0, -1.0]])
    off = np.array([[0.0, 1.8e-3, 0.0], [0.0, 1.8e-3, 0.0]])
    excess = flow_parity_excess(expected + off, expected)  # (2, 3)
    # Row 0: bound 1e-4 + 1e-5 x 2500 = 0.0251, so 1.8e-3 is within; row 1: bound 1e-4 +
    # 1e-5 x 2 = 1.2e-4, so 1.8e-3 is 1.68e-3 beyond.
    assert np.max(excess[0]) <= 0
    assert excess[1, 1] == pytest.approx(1.8e-3 - 1.2e-4)
    # A row is its own scale: a large output elsewhere does not widen it.
    assert np.max(flow_parity_excess(expected[1:] + off[1:], expected[1:])) > 0


def test_kinematics_export_reproduces_pytorch_kinematics_and_refuses_another_arm(
    tmp_path: Path,
) -> None:
    fk = ForwardKinematics(load_chain(URDF, "ee"))
    joints = joint_spec(fk.chain)
    path = tmp_path / "kinematics.onnx"
    export_kinematics(fk, path, joints)
    longer = tmp_path / "longer.urdf"
    longer.write_text(URDF.read_text().replace('xyz="1 0 0"', 'xyz="1.5 0 0"', 1))
    with pytest.raises(ExportParityError, match="'position' differs from pytorch-kinematics"):
        check_kinematics_parity(ForwardKinematics(load_chain(longer, "ee")), path, joints)


@pytest.mark.parametrize("arm", ["planar3r", "twisted"])
def test_chain_export_reproduces_pytorch_kinematics_and_refuses_another_arm(
    arm: str, tmp_path: Path
) -> None:
    if arm == "twisted":
        urdf, end_effector = write_twisted_urdf(tmp_path), TWISTED_END_EFFECTOR
    else:
        urdf, end_effector = URDF, "ee"
    fk = ForwardKinematics(load_chain(urdf, end_effector))
    joints = joint_spec(fk.chain)
    path = tmp_path / CHAIN_FILE
    export_chain(fk, path, joints)  # checks parity itself
    spec = ChainSpec.model_validate_json(path.read_text())
    assert spec.joint_names == joints.names and spec.end_effector_link == end_effector
    moved = json.loads(path.read_text())
    moved["tip"][0][3] += 1e-9  # the tool a nanometre off: beyond 1e-12
    path.write_text(json.dumps(moved))
    with pytest.raises(
        ExportParityError, match=r"'position' differs .* by [0-9.]+e-(09|10) > 1e-12"
    ):
        check_chain_parity(fk, path, joints)


def test_refresh_writes_the_chain_the_registry_serves_and_touches_nothing_else(
    tmp_path: Path,
) -> None:
    model_dir = model_without_chain(tmp_path)
    before = json.loads((model_dir / MANIFEST_FILE).read_text())
    flow_sha = sha256_of(model_dir / FLOW_FILE)
    assert isinstance(load_model(model_dir, threads=1).kinematics, OnnxKinematics)

    refresh_kinematics(model_dir, model_dir.parent)

    after = json.loads((model_dir / MANIFEST_FILE).read_text())
    assert {k: v for k, v in after.items() if k != "files"} == {
        k: v for k, v in before.items() if k != "files"
    }
    assert list(after["files"]) == [*before["files"], CHAIN_FILE]
    assert after["files"][FLOW_FILE] == flow_sha == sha256_of(model_dir / FLOW_FILE)
    assert sorted(p.name for p in model_dir.parent.iterdir()) == [PLANAR3R_DIR.name, "robots"]
    served = load_model(model_dir, threads=1)  # verifies every sha256 and chain vs onnx
    assert isinstance(served.kinematics, SerialChainKinematics)
    q = np.random.default_rng(4).uniform(-np.pi, np.pi, (500, 3))
    assert_chain_equals_onnx(served.kinematics, model_dir, q)


def test_refresh_refuses_another_urdf_and_leaves_the_model_as_it_was(tmp_path: Path) -> None:
    model_dir = model_without_chain(tmp_path)
    urdf = model_dir.parent / "robots" / "planar3r.urdf"
    urdf.write_text(urdf.read_text().replace('xyz="1 0 0"', 'xyz="1.5 0 0"', 1))
    files = {p.name: p.read_bytes() for p in model_dir.iterdir()}
    with pytest.raises(ExportParityError, match=r"planar3r\.urdf: sha256 differs .* \(retrain\)"):
        refresh_kinematics(model_dir, model_dir.parent)
    assert {p.name: p.read_bytes() for p in model_dir.iterdir()} == files
    assert sorted(p.name for p in model_dir.parent.iterdir()) == [PLANAR3R_DIR.name, "robots"]


def test_refresh_starts_the_chain_at_the_recorded_base_link(tmp_path: Path) -> None:
    """A URDF with a "world" link 2 m below base_link: the refreshed chain.json still starts
    at base_link, as the flow was trained (from the root it would be 2 m off)."""
    models = tmp_path / "models"
    shutil.copytree(REPO_MODELS_DIR / "robots", models / "robots")
    model_dir = models / PLANAR3R_DIR.name
    shutil.copytree(PLANAR3R_DIR, model_dir)
    chain_before = (model_dir / CHAIN_FILE).read_text()
    urdf = models / "robots" / "planar3r.urdf"
    urdf.write_text(
        urdf.read_text().replace(
            '<link name="base_link"/>',
            '<link name="world"/><link name="base_link"/><joint name="mount" type="fixed">'
            '<parent link="world"/><child link="base_link"/><origin xyz="0 0 2"/></joint>',
        )
    )
    manifest = json.loads((model_dir / MANIFEST_FILE).read_text())
    manifest["urdf"]["sha256"] = sha256_of(urdf)
    (model_dir / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2) + "\n")

    refresh_kinematics(model_dir, models)

    assert ChainSpec.model_validate_json((model_dir / CHAIN_FILE).read_text()) == (
        ChainSpec.model_validate_json(chain_before)
    )
    served = load_model(model_dir, threads=1)
    position = served.kinematics(np.zeros((1, 3))).position_m
    np.testing.assert_allclose(position, [[3.0, 0.0, 0.0]], rtol=0, atol=1e-15)
