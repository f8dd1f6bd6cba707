"""A URDF read into a validated serial chain: base link to end effector, revolute joints only.

A URDF is a tree (an arm with a gripper has finger branches; a robot on a cart has a
floating joint above the arm). `read_serial_chain` picks the one path from the base link
to the end effector, refuses what the project cannot model on that path (prismatic,
planar or floating joints, mimic joints, revolute joints without limits) with a
ValueError that names the joint or link and lists the valid choices, and returns the
path alone as a URDF (`SerialChainUrdf.urdf_text`): what pytorch-kinematics reads
(`training.kinematics.load_chain`), so the rest of the tree, however exotic, never
reaches it. Fixed joints stay in the chain (chain.json folds them); continuous joints
are periodic (`training.kinematics.joint_spec`). `require_redundancy` refuses a task
with as many task coordinates as joints or more: there is no self-motion to learn.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass

from service.manifest import DEFAULT_TOOL_AXIS, TaskSpec

MOVABLE_TYPES = ("revolute", "continuous")
SUPPORTED_TYPES = (*MOVABLE_TYPES, "fixed")

# The tasks of an arm in space that has no robot file yet (a robot file may declare
# others, e.g. the planar 3R's position in the x-y plane).
SPATIAL_TASKS: dict[str, TaskSpec] = {
    "pose": TaskSpec(name="pose", position_axes=[0, 1, 2], orientation=True),
    "position": TaskSpec(name="position", position_axes=[0, 1, 2], orientation=False),
    "axis": TaskSpec(
        name="axis", position_axes=[0, 1, 2], orientation=False, tool_axis=list(DEFAULT_TOOL_AXIS)
    ),
}

# Robot names become file names (models/robots/<name>.json) and model ids (<name>-<task>).
ROBOT_NAME_PATTERN = re.compile(r"^[a-z0-9_-]+$")


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    limits_rad: tuple[float, float] | None  # (lower, upper) of a revolute joint, else None
    mimics: str | None  # the joint a <mimic> couples it to


@dataclass(frozen=True)
class SerialChainUrdf:
    """The path from `base_link` to `end_effector_link` of a URDF, validated."""

    robot_name: str  # the URDF's <robot name="...">
    base_link: str
    end_effector_link: str
    joints: tuple[UrdfJoint, ...]  # base to end effector, fixed joints included
    urdf_text: str  # a URDF of this path alone (links stripped of geometry)

    @property
    def movable_joint_names(self) -> list[str]:
        return [joint.name for joint in self.joints if joint.type in MOVABLE_TYPES]


def task_for_urdf(name: str) -> TaskSpec:
    """The spatial task `name`; raises with the valid choices otherwise."""
    try:
        return SPATIAL_TASKS[name]
    except KeyError:
        raise ValueError(f"unknown task {name!r}; choose from {sorted(SPATIAL_TASKS)}") from None


def require_redundancy(chain: SerialChainUrdf, task: TaskSpec) -> None:
    """Raise unless the chain's n joints exceed the task's m coordinates (r = n - m >= 1)."""
    n, m = len(chain.movable_joint_names), task.dimension
    if n <= m:
        raise ValueError(
            f"the chain from {chain.base_link!r} to {chain.end_effector_link!r} has n = {n} "
            f"joints {chain.movable_joint_names} and the {task.name!r} task m = {m} "
            f"coordinates: no redundancy (n - m = {n - m}); a self-motion manifold needs "
            f"n > m (choose an end effector further out, or a task with fewer coordinates)"
        )


def sanitise_robot_name(name: str) -> str:
    """`name` lowercased, every character outside [a-z0-9_-] replaced by '_'."""
    cleaned = re.sub(r"[^a-z0-9_-]", "_", name.strip().lower())
    if not cleaned.strip("_-"):
        raise ValueError(f"robot name {name!r} has no letter or digit; pass --name")
    return cleaned


def read_serial_chain(
    urdf_text: str, end_effector_link: str, base_link: str | None = None
) -> SerialChainUrdf:
    """The validated chain from `base_link` (default: the root of the tree) to the end effector."""
    try:
        robot = ET.fromstring(urdf_text)
    except ET.ParseError as error:
        raise ValueError(f"not a URDF: {error}") from None
    if robot.tag != "robot":
        raise ValueError(f"not a URDF: the root element is <{robot.tag}>, not <robot>")
    links = [link.get("name", "") for link in robot.findall("link")]
    joints = [_read_joint(element) for element in robot.findall("joint")]
    for what, link in (("end-effector", end_effector_link), ("base", base_link)):
        if link is not None and link not in links:
            raise ValueError(f"{what} link {link!r} is not in the URDF; links: {links}")
    parent_joint: dict[str, UrdfJoint] = {}
    for joint in joints:
        if joint.child in parent_joint:
            raise ValueError(
                f"link {joint.child!r} is the child of joints {parent_joint[joint.child].name!r} "
                f"and {joint.name!r}: a URDF must be a tree"
            )
        parent_joint[joint.child] = joint

    path: list[UrdfJoint] = []  # end effector to base
    link = end_effector_link
    while link != base_link and link in parent_joint:
        path.append(parent_joint[link])
        link = parent_joint[link].parent
        if len(path) > len(joints):
            raise ValueError(f"the URDF's joints form a cycle through link {link!r}")
    if base_link is not None and link != base_link:
        ancestors = [end_effector_link, *(joint.parent for joint in path)]
        raise ValueError(
            f"base link {base_link!r} is not an ancestor of end effector {end_effector_link!r}; "
            f"choose from its ancestors {ancestors[::-1]}"
        )
    path.reverse()
    for joint in path:
        _check_joint(joint)
    chain_links = {link, *(joint.child for joint in path)}
    chain_joints = {joint.name for joint in path}
    return SerialChainUrdf(
        robot_name=robot.get("name", ""),
        base_link=link,
        end_effector_link=end_effector_link,
        joints=tuple(path),
        urdf_text=_chain_only_urdf(robot, chain_links, chain_joints),
    )


def _read_joint(element: ET.Element) -> UrdfJoint:
    name = element.get("name", "")
    parent, child = element.find("parent"), element.find("child")
    if parent is None or child is None:
        raise ValueError(f"joint {name!r} lacks a <parent> or <child> element")
    limit = element.find("limit")
    kind = element.get("type", "")
    limits = None
    if kind == "revolute" and limit is not None:
        # URDF: a missing lower or upper attribute is 0.
        limits = (float(limit.get("lower", "0")), float(limit.get("upper", "0")))
    mimic = element.find("mimic")
    return UrdfJoint(
        name=name,
        type=kind,
        parent=parent.get("link", ""),
        child=child.get("link", ""),
        limits_rad=limits,
        mimics=None if mimic is None else mimic.get("joint", ""),
    )


def _check_joint(joint: UrdfJoint) -> None:
    where = f"joint {joint.name!r} (from {joint.parent!r} to {joint.child!r})"
    if joint.type not in SUPPORTED_TYPES:
        raise ValueError(
            f"{where} is {joint.type!r}; the chain may hold only {list(SUPPORTED_TYPES)} joints "
            "(choose a base link below it or an end effector before it)"
        )
    if joint.mimics is not None:
        raise ValueError(
            f"{where} mimics joint {joint.mimics!r}; coupled joints are not supported on "
            "the chain (mimic joints are fine off it, e.g. in a gripper)"
        )
    if joint.type != "revolute":
        return
    if joint.limits_rad is None:
        raise ValueError(
            f"revolute {where} has no <limit>: give it lower and upper (rad), or make it "
            "'continuous' if it turns without limits"
        )
    lower, upper = joint.limits_rad
    if not (math.isfinite(lower) and math.isfinite(upper) and lower < upper):
        raise ValueError(
            f"revolute {where} has limits [{lower}, {upper}] rad: lower must be below upper"
        )


def _chain_only_urdf(robot: ET.Element, links: set[str], joints: set[str]) -> str:
    """The URDF of the chain alone: its links (without geometry) and its joints.

    A continuous joint loses its <limit> (it may carry one for effort and velocity, which
    pytorch-kinematics would read as position limits [0, 0]).
    """
    chain = ET.Element("robot", {"name": robot.get("name", "")})
    for element in robot.findall("link"):
        if element.get("name") in links:
            link = ET.SubElement(chain, "link", {"name": element.get("name", "")})
            origin = element.find("origin")  # non-standard, but pytorch-kinematics reads it
            if origin is not None:
                link.append(origin)
    for element in robot.findall("joint"):
        if element.get("name") in joints:
            joint = ET.SubElement(chain, "joint", dict(element.attrib))
            for child in element:
                if not (element.get("type") == "continuous" and child.tag == "limit"):
                    joint.append(child)
    return ET.tostring(chain, encoding="unicode")
