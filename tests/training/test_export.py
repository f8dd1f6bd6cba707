"""export: parity between torch and onnxruntime is checked, and a mismatch fails loudly."""

from pathlib import Path

import pytest
import torch

from service.manifest import REPO_MODELS_DIR
from training.export import (
    ExportParityError,
    check_flow_parity,
    check_kinematics_parity,
    export_flow,
    export_kinematics,
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
