"""register_urdf with collision geometry: the meshes and the SRDF travel with the URDF.

The collision arm registered with an SRDF: its URDF copy, its mesh at the same relative
path beside it and the SRDF as robots/<name>.srdf are byte for byte the sources, and the
robot file names the SRDF; registering the same files again keeps the registration, an
SRDF with other content under the same name is refused, and a mesh named outside the
URDF's directory ('..') is refused by name before anything is written.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.collision_arm import write_collision_arm, write_srdf
from training.robots import register_urdf


def test_the_mesh_and_srdf_are_copied_and_a_different_srdf_is_refused(tmp_path: Path) -> None:
    """Copies equal their sources; the same registration is kept, another SRDF refused."""
    source, models = tmp_path / "source", tmp_path / "models"
    urdf = write_collision_arm(source)
    srdf = write_srdf(source, [("l1", "world")])
    robot = register_urdf(urdf, "tool", "position", models, "base", srdf_path=srdf)
    assert robot.srdf == "robots/collision_arm.srdf"
    assert (models / robot.srdf).read_bytes() == srdf.read_bytes()
    assert (models / robot.urdf).read_bytes() == urdf.read_bytes()
    copied_mesh = models / "robots" / "meshes" / "l2.stl"
    assert copied_mesh.read_bytes() == (source / "meshes" / "l2.stl").read_bytes()
    again = register_urdf(urdf, "tool", "position", models, "base", srdf_path=srdf)
    assert again == robot
    other = write_srdf(tmp_path, [("base", "l3")])
    with pytest.raises(ValueError, match=r"another SRDF"):
        register_urdf(urdf, "tool", "position", models, "base", srdf_path=other)


def test_a_mesh_outside_the_urdfs_directory_is_refused(tmp_path: Path) -> None:
    """'../' in a mesh filename: refused, naming it; no robot file written."""
    urdf = write_collision_arm(tmp_path / "a" / "b", mesh_filename="../b/meshes/l2.stl")
    models = tmp_path / "models"
    with pytest.raises(ValueError, match=r"mesh '\.\./b/meshes/l2\.stl' lies outside"):
        register_urdf(urdf, "tool", "position", models, "base")
    assert not (models / "robots" / "collision_arm.json").exists()
