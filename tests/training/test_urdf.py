"""urdf: a URDF tree is read into the serial chain from the base link to the end effector.

The tests write their own arm (tests/support/small_arm.py): a floating joint from "world"
to "base", four joints with a fixed spacer among them (one continuous), a fixed tool, and
a gripper branch (a prismatic finger, a mimic finger) off the last link. From "base" to
"tool" the chain is picked with its four joints in order, the branch and the floating
joint left out; its forward kinematics equals the tests' own numpy product of the URDF
transforms (Rodrigues about each axis) to 1e-12; the continuous joint is periodic. Each
thing the project cannot model raises a ValueError that names it and the valid choices.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from service.pipeline.joint_space import JointLimits
from tests.support.small_arm import arm_pose, write_arm
from training.kinematics import ForwardKinematics, chain_spec, joint_spec, load_chain
from training.urdf import read_serial_chain, require_redundancy, task_for_urdf


def test_the_chain_from_base_to_tool_is_picked_in_order(tmp_path: Path) -> None:
    chain = read_serial_chain(write_arm(tmp_path).read_text(), "tool", "base")
    assert chain.robot_name == "arm" and chain.base_link == "base"
    assert [j.name for j in chain.joints] == ["j1", "j2", "spacer", "j3", "j4", "tool_fixed"]
    assert chain.movable_joint_names == ["j1", "j2", "j3", "j4"]
    spec = chain_spec(load_chain(write_arm(tmp_path), "tool", "base"))
    assert (spec.base_link, spec.end_effector_link) == ("base", "tool")
    assert spec.joint_names == ["j1", "j2", "j3", "j4"]


def test_forward_kinematics_is_the_product_of_the_urdf_transforms(tmp_path: Path) -> None:
    fk = ForwardKinematics(load_chain(write_arm(tmp_path), "tool", "base"))
    joints = joint_spec(fk.chain)
    limits = JointLimits.of(joints)
    q = np.random.default_rng(0).uniform(limits.lower_rad, limits.upper_rad, (200, 4))
    with torch.no_grad():
        position, rotation, _ = fk(torch.from_numpy(q))
    expected = np.stack([arm_pose(one) for one in q])  # (200, 4, 4)
    np.testing.assert_allclose(position.numpy(), expected[:, :3, 3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(rotation.numpy(), expected[:, :3, :3], rtol=0, atol=1e-12)


def test_limits_and_periodicity_come_from_the_urdf(tmp_path: Path) -> None:
    """The continuous joint's effort/velocity <limit> is not a position limit [0, 0]."""
    joints = joint_spec(load_chain(write_arm(tmp_path), "tool", "base"))
    assert joints.names == ["j1", "j2", "j3", "j4"]
    assert joints.periodic == [False, False, True, False]
    assert joints.lower_rad == [-2.5, -2.0, -math.pi, -1.5]
    assert joints.upper_rad == [2.5, 1.5, math.pi, 2.0]


def test_the_base_defaults_to_the_root_of_the_tree(tmp_path: Path) -> None:
    """From the root "world" the floating cart joint is on the chain: refused, by name."""
    with pytest.raises(ValueError, match=r"joint 'cart' \(from 'world' to 'base'\) is 'floating'"):
        read_serial_chain(write_arm(tmp_path).read_text(), "tool")


@pytest.mark.parametrize("kind", ["prismatic", "planar", "floating"])
def test_a_joint_that_is_not_revolute_on_the_chain_is_named(kind: str, tmp_path: Path) -> None:
    urdf = write_arm(tmp_path, {'"j2" type="revolute"': f'"j2" type="{kind}"'})
    with pytest.raises(ValueError, match=rf"joint 'j2' .* is '{kind}'; the chain may hold only"):
        load_chain(urdf, "tool", "base")


def test_the_gripper_branch_is_ignored_but_refused_as_the_chain(tmp_path: Path) -> None:
    text = write_arm(tmp_path).read_text()
    with pytest.raises(ValueError, match=r"joint 'finger' .* is 'prismatic'"):
        read_serial_chain(text, "finger_l", "base")
    with pytest.raises(ValueError, match=r"joint 'finger_r' .* mimics joint 'finger'"):
        read_serial_chain(text, "finger_r", "base")


def test_unknown_links_are_named_with_the_links_there_are(tmp_path: Path) -> None:
    text = write_arm(tmp_path).read_text()
    with pytest.raises(ValueError, match=r"end-effector link 'flange' is not in the URDF; links: "):
        read_serial_chain(text, "flange", "base")
    with pytest.raises(ValueError, match=r"base link 'floor' is not in the URDF; links: \[.*'l4'"):
        read_serial_chain(text, "tool", "floor")


def test_a_base_that_is_not_an_ancestor_lists_the_ancestors(tmp_path: Path) -> None:
    with pytest.raises(
        ValueError,
        match=r"base link 'finger_l' is not an ancestor of end effector 'tool'; choose from its "
        r"ancestors \['world', 'base', 'l1', 'l2', 'mid', 'l3', 'l4', 'tool'\]",
    ):
        read_serial_chain(write_arm(tmp_path).read_text(), "tool", "finger_l")


def test_a_revolute_joint_needs_limits(tmp_path: Path) -> None:
    no_limit = write_arm(
        tmp_path, {'<limit lower="-1.5" upper="2.0" effort="1" velocity="1"/>': ""}
    ).read_text()
    with pytest.raises(ValueError, match=r"revolute joint 'j4' .* has no <limit>"):
        read_serial_chain(no_limit, "tool", "base")
    empty = write_arm(
        tmp_path, {'<limit lower="-1.5" upper="2.0" effort="1"': '<limit effort="1"'}
    ).read_text()
    with pytest.raises(ValueError, match=r"revolute joint 'j4' .* has limits \[0.0, 0.0\] rad"):
        read_serial_chain(empty, "tool", "base")


def test_a_task_without_redundancy_says_n_and_m(tmp_path: Path) -> None:
    chain = read_serial_chain(write_arm(tmp_path).read_text(), "tool", "base")
    require_redundancy(chain, task_for_urdf("position"))  # n = 4 > m = 3
    with pytest.raises(ValueError, match=r"n = 4 joints .* 'pose' task m = 6 coordinates"):
        require_redundancy(chain, task_for_urdf("pose"))
    short = read_serial_chain(write_arm(tmp_path).read_text(), "l3", "base")  # j1, j2, j3
    with pytest.raises(ValueError, match=r"n = 3 joints \['j1', 'j2', 'j3'\] .* m = 3"):
        require_redundancy(short, task_for_urdf("position"))


def test_an_unknown_task_lists_the_tasks() -> None:
    with pytest.raises(
        ValueError, match=r"unknown task 'orientation'; choose from \['axis', 'pose', 'position'\]"
    ):
        task_for_urdf("orientation")


def test_not_a_urdf_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="not a URDF"):
        read_serial_chain("<robot><link name='a'>", "a")
    with pytest.raises(ValueError, match=r"root element is <sdf>"):
        read_serial_chain("<sdf/>", "a")
