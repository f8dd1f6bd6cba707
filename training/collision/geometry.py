"""The URDF's own collision geometry, body by body, in the chain frames the bodies move with.

A body is one URDF link that has `<collision>` elements and moves with the chain: a link
on the path from the base link to the end effector, or one rigidly attached to it. The
attached links are those reached from the chain through joints that are not on it:

- fixed joints, in either direction (a tool flange below the chain, a world link above
  the base link);
- movable joints off the chain (revolute, continuous, prismatic: a gripper's fingers),
  downwards only, each held at 0 clamped into its limits (the Panda's finger joints sit
  at their lower limit 0, the closed hand); a mimic joint at multiplier x its leader's
  held value + offset. The service knows only the chain's joints, so a finger is a
  fixed part of the hand: the collision model of the gripper as it is held.

Floating and planar joints off the chain are not followed, nor, upwards, any joint but a
fixed one (the base link's parent through a movable joint, a robot's cart, does not
stay fixed to the base): what lies beyond them does not move with the chain.

Each body is expressed in chain frame k as `service.pipeline.collision.frames` defines
it (T_k(q) = origin_1 Rot(axis_1, q_1) ... origin_k Rot(axis_k, q_k), the URDF frame of
chain joint k's child link; 0 for the base link and what is fixed to it), its shapes'
poses in that frame. Meshes are referred to by file: a filename relative to the URDF's
directory, absolute, `file://`, or `package://<package>/<path>` resolved under a package
directory given by the caller.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from service.manifest import ChainSpec
from service.pipeline.arrays import FloatArray
from training.urdf import MOVABLE_TYPES

ShapeKind = Literal["box", "sphere", "cylinder", "capsule", "mesh"]
SHAPE_KINDS: tuple[ShapeKind, ...] = ("box", "sphere", "cylinder", "capsule", "mesh")
# Off-chain joints held at a value (0 clamped into the limits); the others are not followed.
HELD_TYPES = (*MOVABLE_TYPES, "prismatic")


@dataclass(frozen=True)
class Shape:
    """One `<collision>` element: its kind, size and pose in the body's chain frame.

    dimensions_m follow MoveIt's SolidPrimitive: box (x, y, z) full sizes, sphere (r,),
    cylinder (length, r), capsule (length, r) with length the distance between the cap
    centres (URDF's capsule length, coal's lz); a mesh has none and its file and scale.
    """

    kind: ShapeKind
    pose: FloatArray  # (4, 4) in the body's chain frame
    dimensions_m: tuple[float, ...] = ()
    mesh_path: Path | None = None
    mesh_scale: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass(frozen=True)
class Body:
    """A link with collision geometry, the chain frame it moves with, and its shapes."""

    link: str
    frame: int  # 0: the base; k: chain joint k's frame
    shapes: tuple[Shape, ...]


@dataclass(frozen=True)
class _Joint:
    name: str
    type: str
    parent: str
    child: str
    origin: FloatArray  # (4, 4)
    axis: FloatArray  # (3,)
    limits: tuple[float, float] | None
    mimic: tuple[str, float, float] | None  # (leader, multiplier, offset)


def origin_matrix(element: ET.Element | None) -> FloatArray:
    """4x4 transform of a URDF <origin>: translation xyz, then fixed-axis roll, pitch, yaw
    (R = Rz(yaw) Ry(pitch) Rx(roll)); the identity when absent."""
    transform = np.eye(4)
    if element is None:
        return transform
    roll, pitch, yaw = (float(v) for v in element.get("rpy", "0 0 0").split())
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    r_x = np.array([[1.0, 0, 0], [0, cr, -sr], [0, sr, cr]])
    r_y = np.array([[cp, 0, sp], [0, 1.0, 0], [-sp, 0, cp]])
    r_z = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
    transform[:3, :3] = r_z @ r_y @ r_x
    transform[:3, 3] = [float(v) for v in element.get("xyz", "0 0 0").split()]
    return transform


def joint_motion(joint_type: str, axis: FloatArray, value: float) -> FloatArray:
    """4x4 motion of a revolute/continuous (rotation by `value` rad) or prismatic
    (translation by `value` m) joint about/along its unit `axis`."""
    motion = np.eye(4)
    if joint_type == "prismatic":
        motion[:3, 3] = value * axis
        return motion
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    motion[:3, :3] = (
        math.cos(value) * np.eye(3) + math.sin(value) * cross
        + (1.0 - math.cos(value)) * np.outer(axis, axis)
    )  # fmt: skip
    return motion


def _read_joint(element: ET.Element) -> _Joint:
    axis = np.array([float(v) for v in _child(element, "axis", "xyz", "1 0 0").split()])
    limit, mimic = element.find("limit"), element.find("mimic")
    limits = None
    if limit is not None and element.get("type") in ("revolute", "prismatic"):
        limits = (float(limit.get("lower", "0")), float(limit.get("upper", "0")))
    return _Joint(
        name=element.get("name", ""),
        type=element.get("type", ""),
        parent=_child(element, "parent", "link", ""),
        child=_child(element, "child", "link", ""),
        origin=origin_matrix(element.find("origin")),
        axis=axis / np.linalg.norm(axis),
        limits=limits,
        mimic=None
        if mimic is None
        else (
            mimic.get("joint", ""),
            float(mimic.get("multiplier", "1")),
            float(mimic.get("offset", "0")),
        ),
    )


def _child(element: ET.Element, tag: str, attribute: str, default: str) -> str:
    found = element.find(tag)
    return default if found is None else found.get(attribute, default)


def held_value(joint: _Joint, joints: dict[str, _Joint]) -> float:
    """The value an off-chain movable joint is held at: 0 clamped into its limits; a
    mimic joint, multiplier x its leader's held value + offset."""
    if joint.mimic is not None and joint.mimic[0] in joints:
        leader, multiplier, offset = joint.mimic
        return multiplier * held_value(joints[leader], joints) + offset
    if joint.limits is None:
        return 0.0
    return min(max(0.0, joint.limits[0]), joint.limits[1])


def read_bodies(urdf_path: Path, chain: ChainSpec, package_dir: Path | None = None) -> list[Body]:
    """Every link on `chain` or rigidly attached to it that has `<collision>` geometry, in
    the URDF's link order, each in its chain frame (module docstring). `chain` is the
    URDF's chain as chain.json holds it (its base link, end effector and joint names)."""
    robot = ET.fromstring(urdf_path.read_text())
    joints = {j.name: j for j in (_read_joint(e) for e in robot.findall("joint"))}
    placed = _place_links(chain, joints)
    bodies = []
    for element in robot.findall("link"):
        name = element.get("name", "")
        collisions = element.findall("collision")
        if name not in placed or not collisions:
            continue
        frame, link_pose = placed[name]
        shapes = tuple(_read_shape(c, link_pose, urdf_path, package_dir, name) for c in collisions)
        bodies.append(Body(link=name, frame=frame, shapes=shapes))
    return bodies


def _place_links(chain: ChainSpec, joints: dict[str, _Joint]) -> dict[str, tuple[int, FloatArray]]:
    """{link: (chain frame, pose of the link's URDF frame in it)} for the chain's links and
    those rigidly attached to them."""
    by_child = {joint.child: joint for joint in joints.values()}
    path: list[_Joint] = []
    link = chain.end_effector_link
    while link != chain.base_link:
        if link not in by_child:
            raise ValueError(f"URDF: {chain.base_link!r} is not an ancestor of {link!r}")
        path.append(by_child[link])
        link = by_child[link].parent
    path.reverse()
    movable = [joint.name for joint in path if joint.type in MOVABLE_TYPES]
    if movable != chain.joint_names:
        raise ValueError(f"URDF: chain joints {movable} are not chain.json's {chain.joint_names}")
    placed: dict[str, tuple[int, FloatArray]] = {chain.base_link: (0, np.eye(4))}
    frame = 0
    for joint in path:
        pose = placed[joint.parent][1] @ joint.origin
        if joint.type in MOVABLE_TYPES:
            frame, pose = frame + 1, np.eye(4)
        placed[joint.child] = (frame, pose)
    on_path = {joint.name for joint in path}
    pending = list(placed)
    while pending:
        link = pending.pop()
        for _, other, pose in _attached(link, placed[link][1], joints, on_path):
            if other not in placed:
                placed[other] = (placed[link][0], pose)
                pending.append(other)
    return placed


def _attached(
    link: str, pose: FloatArray, joints: dict[str, _Joint], on_path: set[str]
) -> Iterator[tuple[_Joint, str, FloatArray]]:
    """(joint, link, its pose) for the links rigidly attached to `link` by one joint off
    the chain: children through fixed and held movable joints, parents through fixed."""
    for joint in joints.values():
        if joint.name in on_path:
            continue
        if joint.parent == link and joint.type in ("fixed", *HELD_TYPES):
            motion = np.eye(4)
            if joint.type != "fixed":
                motion = joint_motion(joint.type, joint.axis, held_value(joint, joints))
            yield joint, joint.child, pose @ joint.origin @ motion
        elif joint.child == link and joint.type == "fixed":
            yield joint, joint.parent, pose @ np.linalg.inv(joint.origin)


def _read_shape(
    collision: ET.Element, link_pose: FloatArray, urdf_path: Path,
    package_dir: Path | None, link: str,
) -> Shape:  # fmt: skip
    """A <collision> element as a Shape, its pose the link's pose times its <origin>."""
    pose = link_pose @ origin_matrix(collision.find("origin"))
    geometry = collision.find("geometry")
    element = None if geometry is None else next(iter(geometry), None)
    if element is None or element.tag not in SHAPE_KINDS:
        found = None if element is None else element.tag
        raise ValueError(
            f"{urdf_path}: link {link!r} has a <collision> with geometry {found!r}; "
            f"choose from {list(SHAPE_KINDS)}"
        )
    if element.tag == "box":
        size = tuple(float(v) for v in element.get("size", "").split())
        return Shape("box", pose, _positive(size, 3, f"{urdf_path}: link {link!r} box size"))
    if element.tag == "sphere":
        return Shape("sphere", pose, _positive((float(element.get("radius", "0")),), 1, link))
    if element.tag in ("cylinder", "capsule"):
        dims = (float(element.get("length", "0")), float(element.get("radius", "0")))
        return Shape(element.tag, pose, _positive(dims, 2, f"link {link!r} {element.tag}"))
    scale = tuple(float(v) for v in element.get("scale", "1 1 1").split())
    if len(scale) != 3:
        raise ValueError(f"{urdf_path}: link {link!r} mesh scale {scale}: give three numbers")
    path = resolve_mesh(element.get("filename", ""), urdf_path, package_dir, link)
    return Shape("mesh", pose, (), path, (scale[0], scale[1], scale[2]))


def _positive(values: tuple[float, ...], count: int, what: str) -> tuple[float, ...]:
    if len(values) != count or not all(math.isfinite(v) and v > 0 for v in values):
        raise ValueError(f"{what}: {values}; expected {count} positive numbers")
    return values


def resolve_mesh(filename: str, urdf_path: Path, package_dir: Path | None, link: str) -> Path:
    """The file a mesh filename names: relative to the URDF's directory, absolute,
    file://, or package://<package>/<path> as `package_dir`/<package>/<path>."""
    where = f"{urdf_path}: link {link!r} mesh {filename!r}"
    if filename.startswith("package://"):
        if package_dir is None:
            raise ValueError(
                f"{where}: a package:// filename needs a package directory (--package-dir "
                "DIR, holding the package's directory); or write it relative to the URDF's "
                "directory, absolute, or file://"
            )
        path = package_dir / filename.removeprefix("package://")
    elif filename.startswith("file://"):
        path = Path(filename.removeprefix("file://"))
    elif "://" in filename:
        raise ValueError(
            f"{where}: unknown scheme; choose a path relative to the URDF's directory, "
            "an absolute path, file://PATH or package://PACKAGE/PATH"
        )
    else:
        path = urdf_path.parent / filename
    if not path.is_file():
        raise ValueError(f"{where}: no file {path}")
    return path


def mesh_references(urdf_path: Path) -> list[str]:
    """The relative mesh filenames of the URDF's <collision> elements (the files a copy of
    the URDF must take along)."""
    robot = ET.fromstring(urdf_path.read_text())
    names = [mesh.get("filename", "") for mesh in robot.iterfind("link/collision/geometry/mesh")]
    return sorted({n for n in names if "://" not in n and not Path(n).is_absolute()})


def mesh_triangles_m(shape: Shape) -> FloatArray:  # (T, 3, 3): triangle, corner, xyz
    """The triangles of a mesh shape, scaled and placed in its body's chain frame (the file
    read by coal's assimp loader, as the reference checker reads it)."""
    import coal  # a training dependency; the service never imports this module

    if shape.mesh_path is None:
        raise ValueError(f"a {shape.kind} shape has no mesh file")
    model = coal.MeshLoader().load(str(shape.mesh_path), np.asarray(shape.mesh_scale))
    vertices = np.asarray(model.vertices(), dtype=np.float64)  # (V, 3)
    corners = np.array(
        [[t[0], t[1], t[2]] for t in (model.tri_indices(i) for i in range(model.num_tris))],
        dtype=np.int64,
    ).reshape(-1, 3)
    placed = vertices @ shape.pose[:3, :3].T + shape.pose[:3, 3]
    return placed[corners]
