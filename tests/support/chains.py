"""Chains for the kinematics tests: a URDF with every case chain.json has, pytorch-kinematics'
answer on a URDF, and a model directory from before chain.json.

The bundled arms turn every joint about z with origins whose rpy are multiples of pi/2;
the twisted URDF has what they lack: a fixed mounting offset before the first joint, two
consecutive fixed joints between movable ones, axes along y, along -z, oblique and
given unnormalised, origins with arbitrary rpy, a continuous joint, and a fixed tool
offset after the last joint.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import torch

from service.manifest import CHAIN_FILE, KINEMATICS_FILE, MANIFEST_FILE, REPO_MODELS_DIR
from service.models.sessions import OnnxKinematics, open_session
from service.pipeline.joint_space import JointLimits
from service.pipeline.types import Kinematics
from tests.support.app import PLANAR3R_DIR
from training.kinematics import ForwardKinematics, joint_spec, load_chain

TWISTED_URDF = """<?xml version="1.0"?>
<robot name="twisted">
  <link name="base"/> <link name="mount"/> <link name="l1"/> <link name="spacer1"/>
  <link name="spacer2"/> <link name="l2"/> <link name="l3"/> <link name="l4"/>
  <link name="l5"/> <link name="tool"/>
  <joint name="mount_fixed" type="fixed">
    <parent link="base"/> <child link="mount"/>
    <origin xyz="0.1 -0.2 0.3" rpy="0.3 -0.2 0.5"/>
  </joint>
  <joint name="j1" type="revolute">
    <parent link="mount"/> <child link="l1"/>
    <origin xyz="0 0 0.25" rpy="0 0 0.4"/> <axis xyz="0 0 1"/>
    <limit lower="-2.5" upper="2.5" effort="0" velocity="0"/>
  </joint>
  <joint name="spacer_a" type="fixed">
    <parent link="l1"/> <child link="spacer1"/>
    <origin xyz="0.05 0.02 0.1" rpy="1.2 0.1 -0.7"/>
  </joint>
  <joint name="spacer_b" type="fixed">
    <parent link="spacer1"/> <child link="spacer2"/>
    <origin xyz="-0.03 0.07 0.02" rpy="-0.5 0.8 0.3"/>
  </joint>
  <joint name="j2" type="revolute">
    <parent link="spacer2"/> <child link="l2"/>
    <origin xyz="0.3 0 0" rpy="-0.4 0.9 0.2"/> <axis xyz="0 1 0"/>
    <limit lower="-2.0" upper="1.5" effort="0" velocity="0"/>
  </joint>
  <joint name="j3" type="continuous">
    <parent link="l2"/> <child link="l3"/>
    <origin xyz="0 0.2 0.1" rpy="0.1 0.2 0.3"/> <axis xyz="0.6 0 0.8"/>
  </joint>
  <joint name="j4" type="revolute">
    <parent link="l3"/> <child link="l4"/>
    <origin xyz="0.1 0.1 0.1" rpy="2.0 -1.0 0.5"/> <axis xyz="-1 2 0.5"/>
    <limit lower="-3.0" upper="3.0" effort="0" velocity="0"/>
  </joint>
  <joint name="j5" type="revolute">
    <parent link="l4"/> <child link="l5"/>
    <origin xyz="0.2 -0.1 0.05" rpy="-2.5 0.3 1.7"/> <axis xyz="0 0 -1"/>
    <limit lower="-1.0" upper="2.0" effort="0" velocity="0"/>
  </joint>
  <joint name="tool_fixed" type="fixed">
    <parent link="l5"/> <child link="tool"/>
    <origin xyz="0.01 0.02 0.12" rpy="0.2 0 -0.3"/>
  </joint>
</robot>
"""
TWISTED_END_EFFECTOR = "tool"


def model_without_chain(tmp_path: Path) -> Path:
    """A copy of the bundled planar 3R without chain.json, as models exported before it are."""
    models = tmp_path / "models"
    shutil.copytree(REPO_MODELS_DIR / "robots", models / "robots")
    model_dir = models / PLANAR3R_DIR.name
    shutil.copytree(PLANAR3R_DIR, model_dir)
    (model_dir / CHAIN_FILE).unlink(missing_ok=True)
    manifest = json.loads((model_dir / MANIFEST_FILE).read_text())
    manifest["files"].pop(CHAIN_FILE, None)
    (model_dir / MANIFEST_FILE).write_text(json.dumps(manifest, indent=2) + "\n")
    return model_dir


def write_twisted_urdf(directory: Path) -> Path:
    path = directory / "twisted.urdf"
    path.write_text(TWISTED_URDF)
    return path


def pytorch_kinematics_answer(
    urdf: Path, end_effector_link: str, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position (B, 3), rotation (B, 3, 3), jacobian (B, 6, n)) by pytorch-kinematics."""
    fk = ForwardKinematics(load_chain(urdf, end_effector_link))
    with torch.no_grad():
        position, rotation, jacobian = fk(torch.from_numpy(q))
    return position.numpy(), rotation.numpy(), jacobian.numpy()


def configurations(urdf: Path, end_effector_link: str, count: int, seed: int) -> np.ndarray:
    """(count, n) uniform in the joint limits ((-pi, pi] for continuous joints)."""
    joints = joint_spec(load_chain(urdf, end_effector_link))
    limits = JointLimits.of(joints)
    return np.random.default_rng(seed).uniform(
        limits.lower_rad, limits.upper_rad, (count, joints.count)
    )


def assert_chain_equals_onnx(kinematics: Kinematics, model_dir: Path, q_rad: np.ndarray) -> None:
    """The served chain kernel gives what the model's kinematics.onnx gives at q_rad (B, n):
    position, rotation and Jacobian within 1e-12."""
    chain = kinematics(q_rad)
    reference = OnnxKinematics(open_session(model_dir / KINEMATICS_FILE, threads=1))(q_rad)
    np.testing.assert_allclose(chain.position_m, reference.position_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose(chain.rotation, reference.rotation, rtol=0, atol=1e-12)
    np.testing.assert_allclose(chain.jacobian, reference.jacobian, rtol=0, atol=1e-12)
