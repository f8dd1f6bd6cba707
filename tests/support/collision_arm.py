"""A small spatial arm with collision geometry, written by the tests: URDF, STL mesh, SRDF.

    world --fixed--> base --j1 (z)--> l1 --j2 (y)--> l2 --fixed--> mid --j3 (x)--> l3
        --j4 (y)--> l4 --fixed--> tool;  l4 --finger (prismatic)--> finger_a,
        l4 --finger_b (prismatic, mimics finger x -1)--> finger_b

Geometry (COLLISION: link -> [(kind, xyz, rpy, dimensions)], MoveIt's dimensions):
world a box slab on the +y side that l1's arm sweeps into for every j1 above ~0.04 rad
and not at j1 = 0 (the default configuration; j1's limits are [0, 2.8]): an "always"
pair that is not a "default" one; the arm's upper links reach into it sometimes. And a
box touching the tool at the default configuration (all joints 0), 1.17 m up. base a
cylinder, l1 a box and a sphere, l2 a mesh (a box written as a binary STL, scaled by
MESH_SCALE, turned by its origin), mid nothing (l2 and l3 are adjacent through it), l3
a capsule, tool a box, each finger a box overlapping the tool at the fingers' held
values (finger: 0 clamped into [0.01, 0.04], so 0.01; finger_b: -1 x 0.01).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

# (name, type, parent, child, xyz, rpy, axis, limits)
JOINTS: list[tuple[str, str, str, str, tuple, tuple, tuple | None, tuple | None]] = [
    ("mount", "fixed", "world", "base", (0, 0, 0.1), (0, 0, 0), None, None),
    ("j1", "revolute", "base", "l1", (0, 0, 0.2), (0, 0, 0), (0, 0, 1), (0.0, 2.8)),
    ("j2", "revolute", "l1", "l2", (0, 0, 0.15), (0, 0, 0), (0, 1, 0), (-1.5, 1.5)),
    ("spacer", "fixed", "l2", "mid", (0, 0, 0.3), (0, 0, 0.3), None, None),
    ("j3", "revolute", "mid", "l3", (0, 0, 0.02), (0, 0, 0), (1, 0, 0), (-1.0, 1.0)),
    ("j4", "revolute", "l3", "l4", (0, 0, 0.25), (0, 0, 0), (0, 1, 0), (-1.5, 1.5)),
    ("tool_mount", "fixed", "l4", "tool", (0, 0, 0.1), (0, 0, 0), None, None),
    ("finger", "prismatic", "l4", "finger_a", (0, 0, 0.1), (0, 0, 0), (0, 1, 0), (0.01, 0.04)),
    ("finger_b", "prismatic", "l4", "finger_b", (0, 0, 0.1), (0, 0, 0), (0, 1, 0), (-0.04, 0)),
]
LINKS = ["world", "base", "l1", "l2", "mid", "l3", "l4", "tool", "finger_a", "finger_b"]
HELD_M = {"finger": 0.01, "finger_b": -0.01}  # the finger joints' held values
MESH_SCALE = (0.5, 0.5, 1.0)
MESH_BOX_M = ((-0.1, -0.1, 0.0), (0.1, 0.1, 0.25))  # the STL's box, before scaling
COLLISION: dict[str, list[tuple[str, tuple, tuple, tuple]]] = {
    "world": [
        ("box", (0, 0.56, 0.35), (0, 0, 0), (2.0, 0.88, 0.4)),
        ("box", (0, 0, 1.17), (0, 0, 0), (0.1, 0.1, 0.1)),
    ],
    "base": [("cylinder", (0, 0, 0.05), (0, 0, 0), (0.1, 0.05))],
    "l1": [
        ("box", (0.325, 0.05, 0), (0, 0, 0), (0.55, 0.1, 0.05)),
        ("sphere", (0, 0, 0.1), (0, 0, 0), (0.04,)),
    ],
    "l2": [("mesh", (0, 0, 0.02), (0.1, 0, 0.2), ())],
    "l3": [("capsule", (0, 0, 0.12), (0, 0.2, 0), (0.15, 0.03))],
    "tool": [("box", (0, 0, 0), (0, 0, 0), (0.04, 0.04, 0.04))],
    "finger_a": [("box", (0, 0, 0.03), (0, 0, 0), (0.01, 0.01, 0.03))],
    "finger_b": [("box", (0, 0, 0.03), (0, 0, 0), (0.01, 0.01, 0.03))],
}
END_EFFECTOR, BASE = "tool", "base"
# Joined by a joint, through the links without geometry: mid (l2, l3) and l4, whose
# neighbours l3, tool and the two fingers are all adjacent to each other.
ADJACENT = {
    ("base", "world"), ("base", "l1"), ("l1", "l2"), ("l2", "l3"), ("l3", "tool"),
    ("finger_a", "l3"), ("finger_b", "l3"), ("finger_a", "tool"), ("finger_b", "tool"),
    ("finger_a", "finger_b"),
}  # fmt: skip


def box_triangles(low: tuple, high: tuple) -> np.ndarray:
    """(12, 3, 3) the triangles of the box [low, high], outward counter-clockwise."""
    lo, hi = np.asarray(low, float), np.asarray(high, float)
    corner = np.array([[(hi if (i >> k) & 1 else lo)[k] for k in range(3)] for i in range(8)])
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    triangles = []
    for a, b, c, d in faces:
        triangles += [corner[[a, b, c]], corner[[a, c, d]]]
    return np.array(triangles)


def write_stl(path: Path, triangles: np.ndarray) -> None:
    """Binary STL: an 80-byte header, a uint32 count, then per triangle its normal and
    three corners (12 float32) and a uint16 attribute."""
    data = bytearray(b"box written by tests/support/collision_arm.py".ljust(80, b" "))
    data += struct.pack("<I", len(triangles))
    for triangle in triangles:
        normal = np.cross(triangle[1] - triangle[0], triangle[2] - triangle[0])
        normal = normal / np.linalg.norm(normal)
        data += struct.pack("<12fH", *normal, *triangle.ravel(), 0)
    path.write_bytes(bytes(data))


def _geometry(kind: str, dimensions: tuple, mesh_filename: str) -> str:
    if kind == "box":
        return f'<box size="{" ".join(map(str, dimensions))}"/>'
    if kind == "sphere":
        return f'<sphere radius="{dimensions[0]}"/>'
    if kind in ("cylinder", "capsule"):
        return f'<{kind} length="{dimensions[0]}" radius="{dimensions[1]}"/>'
    scale = " ".join(map(str, MESH_SCALE))
    return f'<mesh filename="{mesh_filename}" scale="{scale}"/>'


def write_collision_arm(
    directory: Path, mesh_filename: str = "meshes/l2.stl", name: str = "collision_arm"
) -> Path:
    """The arm's URDF in `directory` (its mesh at `directory`/meshes/l2.stl, named in the
    URDF by `mesh_filename`)."""
    (directory / "meshes").mkdir(parents=True, exist_ok=True)
    write_stl(directory / "meshes" / "l2.stl", box_triangles(*MESH_BOX_M))
    text = f'<?xml version="1.0"?>\n<robot name="{name}">\n'
    for link in LINKS:
        text += f'<link name="{link}">'
        for kind, xyz, rpy, dimensions in COLLISION.get(link, []):
            text += (
                f'<collision><origin xyz="{" ".join(map(str, xyz))}" '
                f'rpy="{" ".join(map(str, rpy))}"/><geometry>'
                f"{_geometry(kind, dimensions, mesh_filename)}</geometry></collision>"
            )
        text += "</link>\n"
    for joint, kind, parent, child, xyz, rpy, axis, limits in JOINTS:
        text += (
            f'<joint name="{joint}" type="{kind}"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="{" ".join(map(str, xyz))}" '
            f'rpy="{" ".join(map(str, rpy))}"/>'
        )
        if axis is not None:
            text += f'<axis xyz="{" ".join(map(str, axis))}"/>'
        if limits is not None:
            text += f'<limit lower="{limits[0]}" upper="{limits[1]}" effort="1" velocity="1"/>'
        if joint == "finger_b":
            text += '<mimic joint="finger" multiplier="-1"/>'
        text += "</joint>\n"
    path = directory / f"{name}.urdf"
    path.write_text(text + "</robot>\n")
    return path


def write_srdf(directory: Path, pairs: list[tuple[str, str]]) -> Path:
    """An SRDF whose disable_collisions are `pairs` (reason "Never")."""
    text = '<?xml version="1.0"?>\n<robot name="collision_arm">\n'
    text += "".join(
        f'<disable_collisions link1="{a}" link2="{b}" reason="Never"/>\n' for a, b in pairs
    )
    path = directory / "collision_arm.srdf"
    path.write_text(text + "</robot>\n")
    return path
