"""training.collision.geometry: the URDF's collision shapes, each in its chain frame.

On a small arm the test writes (tests/support/collision_arm.py): every link with geometry
on the chain or attached to it is a body (the world link above the base through a fixed
joint, the tool through a fixed joint, the fingers through prismatic joints held at 0
clamped into their limits and a mimic), in the frame of its last chain joint, with its
kinds and MoveIt dimensions; each shape placed by chain_frames equals the link's pose by
pytorch-kinematics over the whole tree (fingers at their held values) times the
collision origin; the mesh is the STL's box scaled; mesh filenames resolve relative,
absolute, file:// and package:// (with a package directory; without one the error says
how), and a geometry the URDF does not define is refused with the valid choices.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import pytorch_kinematics as pk
import torch

from service.manifest import ChainSpec, JointSpec
from service.pipeline.collision.frames import chain_frames
from service.pipeline.joint_space import JointLimits
from tests.support.collision_arm import (
    COLLISION,
    HELD_M,
    MESH_BOX_M,
    MESH_SCALE,
    write_collision_arm,
)
from training.collision.geometry import mesh_triangles_m, read_bodies
from training.evaluate.references.urdf_chain import origin_matrix


def test_every_attached_link_with_geometry_is_a_body_in_its_chain_frame(
    arm_urdf: Path, arm_chain: ChainSpec
) -> None:
    """Bodies, frames, shape kinds and dimensions as the test's arm defines them."""
    bodies = read_bodies(arm_urdf, arm_chain)
    assert [(b.link, b.frame) for b in bodies] == [
        ("world", 0), ("base", 0), ("l1", 1), ("l2", 2), ("l3", 3), ("tool", 4),
        ("finger_a", 4), ("finger_b", 4),
    ]  # fmt: skip
    for body in bodies:
        written = COLLISION[body.link]
        assert [s.kind for s in body.shapes] == [kind for kind, *_ in written]
        for shape, (_, _, _, dimensions) in zip(body.shapes, written, strict=True):
            assert shape.dimensions_m == tuple(float(d) for d in dimensions)
    (mesh,) = bodies[3].shapes
    assert mesh.mesh_path == arm_urdf.parent / "meshes" / "l2.stl"
    assert mesh.mesh_scale == MESH_SCALE


def test_each_shape_sits_where_pytorch_kinematics_puts_its_link(
    arm_urdf: Path, arm_chain: ChainSpec, arm_joints: JointSpec
) -> None:
    """T_frame(q) @ shape pose == pk's link pose (whole tree, fingers held) @ origin."""
    tree_urdf = re.sub(r"<collision>.*?</collision>", "", arm_urdf.read_text())
    tree = pk.build_chain_from_urdf(tree_urdf.encode()).to(dtype=torch.float64)
    limits = JointLimits.of(arm_joints)
    q = np.random.default_rng(3).uniform(limits.lower_rad, limits.upper_rad, size=(16, 4))
    held = np.tile([HELD_M["finger"], HELD_M["finger_b"]], (len(q), 1))
    assert tree.get_joint_parameter_names() == ["j1", "j2", "j3", "j4", "finger", "finger_b"]
    links = tree.forward_kinematics(torch.from_numpy(np.hstack([q, held])))
    base_inverse = np.linalg.inv(links["base"].get_matrix().numpy())  # pk's root is world
    frames = chain_frames(arm_chain, q)
    for body in read_bodies(arm_urdf, arm_chain):
        link_pose = base_inverse @ links[body.link].get_matrix().numpy()
        for shape, (_, xyz, rpy, _) in zip(body.shapes, COLLISION[body.link], strict=True):
            expected = link_pose @ origin_matrix(np.asarray(xyz, float), np.asarray(rpy, float))
            # pytorch-kinematics parses URDF origins in float32: ~3e-8 off float64
            np.testing.assert_allclose(frames[:, body.frame] @ shape.pose, expected, atol=1e-7)


def test_the_mesh_is_the_stl_scaled_and_placed(arm_urdf: Path, arm_chain: ChainSpec) -> None:
    """The mesh's triangles, brought back by the inverse of its pose, span the STL's box
    scaled per axis."""
    (mesh,) = read_bodies(arm_urdf, arm_chain)[3].shapes
    triangles = mesh_triangles_m(mesh).reshape(-1, 3)
    local = (triangles - mesh.pose[:3, 3]) @ mesh.pose[:3, :3]
    low, high = (np.asarray(corner) * MESH_SCALE for corner in MESH_BOX_M)
    np.testing.assert_allclose(local.min(axis=0), low, atol=1e-7)  # STL stores float32
    np.testing.assert_allclose(local.max(axis=0), high, atol=1e-7)
    assert len(mesh_triangles_m(mesh)) == 12


@pytest.mark.parametrize("form", ["absolute", "file", "package"])
def test_mesh_filenames_resolve_in_every_form(
    tmp_path: Path, arm_chain: ChainSpec, form: str
) -> None:
    """Absolute, file:// and package://PKG/PATH (under the package directory) filenames
    name the same STL."""
    stl = tmp_path / "pkg" / "meshes" / "l2.stl"
    filename = {
        "absolute": str(stl), "file": f"file://{stl}", "package": "package://pkg/meshes/l2.stl",
    }[form]  # fmt: skip
    urdf = write_collision_arm(tmp_path / "pkg", mesh_filename=filename)
    package_dir = tmp_path if form == "package" else None
    (mesh,) = read_bodies(urdf, arm_chain, package_dir)[3].shapes
    assert mesh.mesh_path is not None and mesh.mesh_path.resolve() == stl.resolve()


def test_unresolvable_meshes_and_unknown_geometry_are_refused_by_name(
    tmp_path: Path, arm_chain: ChainSpec
) -> None:
    """package:// without a package directory, a missing file, and a <cone> are errors
    that name the link and say what is valid."""
    urdf = write_collision_arm(tmp_path, mesh_filename="package://pkg/l2.stl")
    with pytest.raises(ValueError, match=r"link 'l2' mesh 'package://pkg/l2.stl'.*package-dir"):
        read_bodies(urdf, arm_chain)
    with pytest.raises(ValueError, match=r"no file .*missing"):
        read_bodies(urdf, arm_chain, tmp_path / "missing")
    urdf = write_collision_arm(tmp_path)
    urdf.write_text(urdf.read_text().replace('<sphere radius="0.04"/>', '<cone radius="1"/>'))
    with pytest.raises(ValueError, match=r"link 'l1'.*'cone'; choose from \['box', 'sphere'"):
        read_bodies(urdf, arm_chain)
