"""kinematics: URDF joints become the manifest's joint spec, and the iiwa14 URDF
(models/robots/iiwa14.urdf) as read by `load_chain` equals the paper's DH table.

The planar 3R's continuous joints are periodic with limits pi. For the iiwa14, FK is checked
against the DH evaluation of the references (training/evaluate/references/iiwa14.py)
in float64, the geometric Jacobian against central finite differences of that DH FK, and the joint
limits against the paper's degrees. Raw pytorch-kinematics (float32 origins) is ~1e-8 m
off; `load_chain` must be exact. `chain_spec` (chain.json) refuses a prismatic joint.
The measured reach equals the closed forms: 3 m for the planar 3R (three unit links
stretched out), 0.36 + 0.42 + 0.40 + 0.126 m for the iiwa14 (straight up), to 1e-6 m.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from service.manifest import REPO_MODELS_DIR
from training.evaluate.references.iiwa14 import LIMITS_RAD
from training.evaluate.references.iiwa14 import dh_pose as iiwa14_pose
from training.kinematics import (
    ForwardKinematics,
    chain_spec,
    joint_spec,
    load_chain,
    measured_reach_m,
)
from training.robots import robot_spec

URDF = REPO_MODELS_DIR / "robots" / "iiwa14.urdf"
PLANAR = robot_spec("planar3r")


@pytest.fixture(scope="module")
def fk() -> ForwardKinematics:
    return ForwardKinematics(load_chain(URDF, "ee"))


def _configurations(count: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-LIMITS_RAD, LIMITS_RAD, (count, 7))


def test_continuous_joints_are_periodic_with_limits_pi() -> None:
    chain = load_chain(REPO_MODELS_DIR / PLANAR.urdf, PLANAR.end_effector_link)
    joints = joint_spec(chain)
    assert joints.names == ["joint1", "joint2", "joint3"]
    assert joints.periodic == [True, True, True]
    assert joints.lower_rad == [-math.pi] * 3 and joints.upper_rad == [math.pi] * 3


def test_forward_kinematics_equals_the_dh_table(fk: ForwardKinematics) -> None:
    q = _configurations(1000, 0)
    position, rotation, _ = fk(torch.from_numpy(q))
    expected = iiwa14_pose(q)
    np.testing.assert_allclose(position.numpy(), expected[:, :3, 3], rtol=0, atol=1e-14)
    np.testing.assert_allclose(rotation.numpy(), expected[:, :3, :3], rtol=0, atol=1e-14)


def test_zero_configuration_is_straight_up_with_the_flange_offset(fk: ForwardKinematics) -> None:
    position, rotation, _ = fk(torch.zeros(1, 7, dtype=torch.float64))
    np.testing.assert_allclose(position.numpy()[0], [0, 0, 0.36 + 0.42 + 0.40 + 0.126], atol=1e-15)
    np.testing.assert_allclose(rotation.numpy()[0], np.eye(3), atol=1e-15)


def test_jacobian_equals_finite_differences_of_the_dh_table(fk: ForwardKinematics) -> None:
    q = _configurations(100, 1)
    _, _, jacobian = fk(torch.from_numpy(q))
    jacobian_np = jacobian.numpy()  # (B, 6, 7)
    step = 1e-6
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = step
        forward, backward = iiwa14_pose(q + dq), iiwa14_pose(q - dq)
        linear = (forward[:, :3, 3] - backward[:, :3, 3]) / (2 * step)
        # Angular velocity: log of the rotation increment, R(q + dq) R(q - dq)^T.
        increment = forward[:, :3, :3] @ np.swapaxes(backward[:, :3, :3], 1, 2)
        angular = Rotation.from_matrix(increment).as_rotvec() / (2 * step)
        np.testing.assert_allclose(jacobian_np[:, :3, j], linear, atol=1e-8)
        np.testing.assert_allclose(jacobian_np[:, 3:, j], angular, atol=1e-8)


def test_joint_limits_are_the_papers(fk: ForwardKinematics) -> None:
    joints = joint_spec(fk.chain)
    np.testing.assert_allclose(joints.upper_rad, LIMITS_RAD, rtol=0, atol=1e-15)
    np.testing.assert_allclose(joints.lower_rad, -LIMITS_RAD, rtol=0, atol=1e-15)
    assert joints.periodic == [False] * 7


def test_the_float32_origins_of_pytorch_kinematics_are_replaced() -> None:
    import pytorch_kinematics as pk

    q = _configurations(200, 2)
    raw = pk.build_serial_chain_from_urdf(URDF.read_bytes(), "ee").to(dtype=torch.float64)
    raw_error = np.abs(
        raw.forward_kinematics(torch.from_numpy(q)).get_matrix().numpy()[:, :3, 3]
        - iiwa14_pose(q)[:, :3, 3]
    ).max()
    assert raw_error > 1e-9  # the defect load_chain exists for; if it vanishes, simplify


def test_chain_spec_refuses_a_prismatic_joint(tmp_path: Path) -> None:
    """chain.json (and the service's kernel) model revolute and continuous joints only: the
    URDF reader refuses a prismatic joint by name, and chain_spec refuses one in a chain
    built by pytorch-kinematics directly."""
    urdf = tmp_path / "slider.urdf"
    urdf.write_text(
        '<robot name="slider"><link name="base"/><link name="a"/><link name="ee"/>'
        '<joint name="turn" type="continuous"><parent link="base"/><child link="a"/>'
        '<axis xyz="0 0 1"/></joint>'
        '<joint name="slide" type="prismatic"><parent link="a"/><child link="ee"/>'
        '<axis xyz="1 0 0"/><limit lower="0" upper="1" effort="0" velocity="0"/></joint>'
        "</robot>"
    )
    with pytest.raises(ValueError, match=r"joint 'slide' \(from 'a' to 'ee'\) is 'prismatic'"):
        load_chain(urdf, "ee")  # training.urdf refuses it first
    import pytorch_kinematics as pk

    raw = pk.build_serial_chain_from_urdf(urdf.read_bytes(), "ee").to(dtype=torch.float64)
    with pytest.raises(ValueError, match="joint 'slide': only revolute and continuous joints"):
        chain_spec(raw)


def test_measured_reach_is_the_closed_form(fk: ForwardKinematics) -> None:
    planar = ForwardKinematics(load_chain(REPO_MODELS_DIR / PLANAR.urdf, PLANAR.end_effector_link))
    assert abs(measured_reach_m(planar.chain, joint_spec(planar.chain)) - 3.0) <= 1e-6
    iiwa_reach_m = 0.36 + 0.42 + 0.40 + 0.126
    assert abs(measured_reach_m(fk.chain, joint_spec(fk.chain)) - iiwa_reach_m) <= 1e-6
