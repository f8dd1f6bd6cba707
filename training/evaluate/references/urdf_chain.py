"""A float64 forward kinematics of a URDF chain, independent of the service and the export.

Reads the URDF with xml.etree (not pytorch-kinematics, which parses origins in float32,
nor training.kinematics, nor the service's chain.json kernel): the chain from the base
link to the end-effector link is the product, joint by joint, of the joint's origin
(translation xyz, then the fixed-axis roll-pitch-yaw rotation Rz(yaw) Ry(pitch)
Rx(roll)) and its motion: a rotation by q about the unit joint axis (Rodrigues) for
revolute and continuous joints, a translation by q along it for prismatic ones, nothing
for fixed ones. The tests check the references' DH tables with it, and
tools/container_test checks the Panda's answers with it.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from training.evaluate.references.rotations import rodrigues

MOVABLE = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    kind: str  # revolute, continuous, prismatic or fixed
    origin: np.ndarray  # (4, 4) child joint frame in the parent link frame at q = 0
    axis: np.ndarray  # (3,) unit, in the joint frame
    lower: float  # limits (-inf, inf for continuous and fixed joints)
    upper: float


@dataclass(frozen=True)
class UrdfChain:
    joints: tuple[UrdfJoint, ...]  # base to end effector, fixed joints included

    @property
    def movable(self) -> tuple[UrdfJoint, ...]:
        return tuple(j for j in self.joints if j.kind in MOVABLE)

    @property
    def lower(self) -> np.ndarray:
        return np.array([j.lower for j in self.movable])

    @property
    def upper(self) -> np.ndarray:
        return np.array([j.upper for j in self.movable])

    def frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(B, n, 4, 4) the frame of each movable joint (after its origin, before its
        motion) and (B, 4, 4) the end-effector pose, for configurations q (B, n)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pose = np.tile(np.eye(4), (len(q), 1, 1))  # (B, 4, 4)
        frames = []
        column = 0
        for joint in self.joints:
            pose = pose @ joint.origin
            if joint.kind not in MOVABLE:
                continue
            frames.append(pose)
            motion = np.tile(np.eye(4), (len(q), 1, 1))
            if joint.kind == "prismatic":
                motion[:, :3, 3] = q[:, column, None] * joint.axis
            else:
                motion[:, :3, :3] = rodrigues(joint.axis, q[:, column])
            pose = pose @ motion
            column += 1
        if column != q.shape[1]:
            raise ValueError(f"the chain has {column} movable joints, q has {q.shape[1]}")
        return np.stack(frames, axis=1), pose

    def pose(self, q: np.ndarray) -> np.ndarray:
        """(B, 4, 4) end-effector poses of configurations q (B, n)."""
        return self.frames(q)[1]

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """(B, 6, n) geometric Jacobian in the base frame: linear velocity of the end
        effector over angular velocity, for revolute joints axis x (p - joint origin)."""
        frames, pose = self.frames(q)
        axes = np.einsum("bnij,nj->bni", frames[..., :3, :3], [j.axis for j in self.movable])
        prismatic = np.array([j.kind == "prismatic" for j in self.movable])
        lever = pose[:, None, :3, 3] - frames[..., :3, 3]  # (B, n, 3)
        linear = np.where(prismatic[None, :, None], axes, np.cross(axes, lever))
        angular = np.where(prismatic[None, :, None], 0.0, axes)
        return np.concatenate([linear, angular], axis=2).transpose(0, 2, 1)


def origin_matrix(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    """(4, 4) a URDF origin: Rz(yaw) Ry(pitch) Rx(roll), then the translation xyz."""
    ex, ey, ez = np.eye(3)
    roll, pitch, yaw = rpy
    transform = np.eye(4)
    transform[:3, :3] = (
        rodrigues(ez, np.array([yaw]))[0]
        @ rodrigues(ey, np.array([pitch]))[0]
        @ rodrigues(ex, np.array([roll]))[0]
    )
    transform[:3, 3] = xyz
    return transform


def _attribute(element: ET.Element, tag: str, attribute: str) -> str:
    """The attribute of element's required child `tag` (a joint's parent or child link)."""
    child = element.find(tag)
    value = None if child is None else child.get(attribute)
    if value is None:
        raise ValueError(f"joint {element.get('name')!r} has no <{tag} {attribute}=...>")
    return value


def _floats(element: ET.Element | None, attribute: str, default: str) -> np.ndarray:
    text = default if element is None else element.get(attribute, default)
    return np.array([float(v) for v in text.split()])


def read_chain(urdf: Path | str, end_effector_link: str, base_link: str | None = None) -> UrdfChain:
    """The chain from `base_link` (default: the root of the tree) to `end_effector_link`."""
    root = ET.fromstring(Path(urdf).read_text() if isinstance(urdf, Path) else urdf)
    links = sorted(str(link.get("name")) for link in root.iter("link"))
    if end_effector_link not in links or (base_link is not None and base_link not in links):
        raise ValueError(f"unknown link {end_effector_link!r} or {base_link!r}; links: {links}")
    by_child = {_attribute(j, "child", "link"): j for j in root.iter("joint")}
    joints: list[UrdfJoint] = []
    link = end_effector_link
    while link != base_link and link in by_child:
        element = by_child[link]
        kind = element.get("type", "fixed")
        origin = element.find("origin")
        axis = _floats(element.find("axis"), "xyz", "1 0 0")
        limit = element.find("limit")
        bounded = kind in ("revolute", "prismatic") and limit is not None
        joints.append(
            UrdfJoint(
                name=element.get("name", ""),
                kind=kind,
                origin=origin_matrix(
                    _floats(origin, "xyz", "0 0 0"), _floats(origin, "rpy", "0 0 0")
                ),
                axis=axis / np.linalg.norm(axis),
                lower=_floats(limit, "lower", "0")[0] if bounded else -np.inf,
                upper=_floats(limit, "upper", "0")[0] if bounded else np.inf,
            )
        )
        link = _attribute(element, "parent", "link")
    if base_link is not None and link != base_link:
        raise ValueError(f"{end_effector_link!r} does not descend from {base_link!r}")
    return UrdfChain(tuple(reversed(joints)))
