"""references.urdf_chain: the float64 FK of a URDF chain, the tests' and the container
test's independent check of the references' DH tables and of the served answers.

On a planar arm written for the test (an offset base-to-tip chain, an unnormalised axis,
a continuous joint, a fixed tool with a yaw) the pose equals the closed form to 1e-12;
the limits are read (infinite for a continuous joint); on the bundled iiwa14 the
geometric Jacobian equals central differences of the pose (linear and angular rows, 1e-8);
a link outside the chain or a base that is not an ancestor is refused by name; and URDF
origins are the fixed-axis roll-pitch-yaw rotation (scipy's extrinsic "xyz" Euler angles)
then the translation.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from service.manifest import REPO_MODELS_DIR
from training.evaluate.references.iiwa14 import LIMITS_RAD
from training.evaluate.references.urdf_chain import origin_matrix, read_chain

PLANAR_URDF = """<robot name="planar">
  <link name="base"/> <link name="l1"/> <link name="l2"/> <link name="tip"/>
  <joint name="j1" type="revolute"> <parent link="base"/> <child link="l1"/>
    <origin xyz="0 0 0" rpy="0 0 0"/> <axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="0" velocity="0"/> </joint>
  <joint name="j2" type="continuous"> <parent link="l1"/> <child link="l2"/>
    <origin xyz="0.7 0 0" rpy="0 0 0"/> <axis xyz="0 0 2"/> </joint>
  <joint name="tool" type="fixed"> <parent link="l2"/> <child link="tip"/>
    <origin xyz="0.4 0 0" rpy="0 0 0.5"/> </joint>
</robot>"""


def test_urdf_chain_matches_a_closed_form_planar_arm() -> None:
    planar = read_chain(PLANAR_URDF, "tip")
    q = np.random.default_rng(0).uniform(-3, 3, (100, 2))
    pose = planar.pose(q)
    angle = q[:, 0] + q[:, 1]
    x = 0.7 * np.cos(q[:, 0]) + 0.4 * np.cos(angle)
    y = 0.7 * np.sin(q[:, 0]) + 0.4 * np.sin(angle)
    np.testing.assert_allclose(pose[:, :3, 3], np.stack([x, y, 0 * x], 1), rtol=0, atol=1e-12)
    heading = angle + 0.5
    np.testing.assert_allclose(pose[:, 0, :2], np.stack([np.cos(heading), -np.sin(heading)], 1),
                               rtol=0, atol=1e-12)  # fmt: skip
    assert planar.lower[0] == -3 and planar.upper[1] == np.inf


def test_urdf_chain_jacobian_is_the_differences_of_its_pose() -> None:
    iiwa = read_chain(REPO_MODELS_DIR / "robots" / "iiwa14.urdf", "ee")
    q = np.random.default_rng(1).uniform(-LIMITS_RAD, LIMITS_RAD, (5, 7))
    step = 1e-6
    ahead = np.stack([iiwa.pose(q + step * e) for e in np.eye(7)], -1)  # (5, 4, 4, 7)
    behind = np.stack([iiwa.pose(q - step * e) for e in np.eye(7)], -1)
    linear = (ahead[:, :3, 3] - behind[:, :3, 3]) / (2 * step)  # (5, 3, 7)
    turn = np.einsum("bijn,bkjn->bikn", ahead[:, :3, :3], behind[:, :3, :3])  # R+ R-^T
    skew = (turn - np.swapaxes(turn, 1, 2)) / 2
    angular = np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], 1) / (2 * step)
    expected = np.concatenate([linear, angular], 1)
    np.testing.assert_allclose(iiwa.jacobian(q), expected, rtol=0, atol=1e-8)


def test_unknown_links_and_a_base_off_the_path_are_refused() -> None:
    with pytest.raises(ValueError, match="unknown link 'nowhere'"):
        read_chain(PLANAR_URDF, "nowhere")
    with pytest.raises(ValueError, match="does not descend from 'tip'"):
        read_chain(PLANAR_URDF, "l1", base_link="tip")


def test_an_origin_is_the_fixed_axis_roll_pitch_yaw_then_the_translation() -> None:
    rpy = np.array([0.3, -1.1, 2.4])
    xyz = np.array([0.1, -0.2, 0.5])
    origin = origin_matrix(xyz, rpy)
    expected = Rotation.from_euler("xyz", rpy).as_matrix()  # extrinsic x, then y, then z
    np.testing.assert_allclose(origin[:3, :3], expected, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(origin[:3, 3], xyz)
    np.testing.assert_array_equal(origin[3], [0, 0, 0, 1])
