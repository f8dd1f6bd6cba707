"""A small arm the tests write themselves: a URDF tree and its own numpy forward kinematics.

A floating joint from "world" to "base" (a robot on a cart), four joints (revolute,
revolute, a fixed spacer, continuous with an effort/velocity <limit>, revolute about an
unnormalised oblique axis), a fixed tool, and a gripper branch off the last link (a
prismatic finger and a revolute finger that mimics it). `arm_pose` multiplies the URDF's
transforms out from the same numbers the URDF is written from (origin: translation,
then Rz(yaw) Ry(pitch) Rx(roll); motion: Rodrigues about the unit axis), with neither
pytorch-kinematics nor the training code under test (the origin and Rodrigues helpers of
training/evaluate/references/).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from training.evaluate.references.rotations import rodrigues
from training.evaluate.references.urdf_chain import origin_matrix

# (name, type, parent, child, xyz, rpy, axis, limits): the arm the URDF is written from.
JOINTS: list[tuple[str, str, str, str, tuple, tuple, tuple | None, tuple | None]] = [
    ("cart", "floating", "world", "base", (1, 2, 0), (0, 0, 0), None, None),
    ("j1", "revolute", "base", "l1", (0.0, 0.0, 0.3), (0.0, 0.0, 0.4), (0, 0, 1), (-2.5, 2.5)),
    ("j2", "revolute", "l1", "l2", (0.05, 0.0, 0.2), (0.1, 0.0, 0.0), (0, 1, 0), (-2.0, 1.5)),
    ("spacer", "fixed", "l2", "mid", (0.0, 0.0, 0.4), (0.0, 0.3, -0.2), None, None),
    ("j3", "continuous", "mid", "l3", (0.0, 0.05, 0.1), (-0.3, 0.2, 0.1), (1, 0, 0), None),
    ("j4", "revolute", "l3", "l4", (0.1, 0.0, 0.3), (0.2, -0.1, 0.4), (0, 1, 1), (-1.5, 2.0)),
    ("tool_fixed", "fixed", "l4", "tool", (0.0, 0.02, 0.12), (0.0, 0.0, 0.5), None, None),
    ("finger", "prismatic", "l4", "finger_l", (0, 0.03, 0.1), (0, 0, 0), (0, 1, 0), (0, 0.04)),
    ("finger_r", "revolute", "l4", "finger_r", (0, -0.03, 0.1), (0, 0, 0), (1, 0, 0), (0, 1)),
]
LINKS = ["world", "base", "l1", "l2", "mid", "l3", "l4", "tool", "finger_l", "finger_r"]


def write_arm(directory: Path, replace: dict[str, str] | None = None, name: str = "arm") -> Path:
    """The arm's URDF; `replace` swaps text in the joints' XML (e.g. a joint's type)."""
    joints = []
    for joint, kind, parent, child, xyz, rpy, axis, limits in JOINTS:
        xml = (
            f'<joint name="{joint}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="{" ".join(map(str, xyz))}" '
            f'rpy="{" ".join(map(str, rpy))}"/>'
        )
        if axis is not None:
            xml += f'<axis xyz="{" ".join(map(str, axis))}"/>'
        if limits is not None:
            xml += f'<limit lower="{limits[0]}" upper="{limits[1]}" effort="1" velocity="1"/>'
        elif kind == "continuous":  # effort and velocity only: no position limits
            xml += '<limit effort="1" velocity="1"/>'
        if joint == "finger_r":
            xml += '<mimic joint="finger" multiplier="1"/>'
        joints.append(xml + "</joint>")
    text = f'<?xml version="1.0"?>\n<robot name="{name}">\n'
    text += "".join(f'<link name="{link}"><visual><geometry><box size="0.1 0.1 0.1"/>'
                    "</geometry></visual></link>\n" for link in LINKS)  # fmt: skip
    text += "\n".join(joints) + "\n</robot>\n"
    for old, new in (replace or {}).items():
        assert old in text
        text = text.replace(old, new)
    path = directory / "arm.urdf"
    path.write_text(text)
    return path


def arm_pose(q: np.ndarray) -> np.ndarray:
    """The tool's pose (4, 4) in the frame of "base" at q (4,) (the chain from "base" to
    "tool"): the URDF's transforms multiplied out."""
    pose, column = np.eye(4), 0
    for name, kind, *_, xyz, rpy, axis, _ in JOINTS[1:7]:  # base to tool
        pose = pose @ origin_matrix(np.asarray(xyz, float), np.asarray(rpy, float))
        if kind != "fixed":
            assert axis is not None, name
            motion = np.eye(4)
            motion[:3, :3] = rodrigues(
                np.asarray(axis) / np.linalg.norm(axis), q[column : column + 1]
            )[0]
            pose = pose @ motion
            column += 1
    return pose
