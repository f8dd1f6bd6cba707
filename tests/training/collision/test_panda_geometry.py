"""The bundled Panda's collision geometry: back in its URDF, its kinematics untouched.

models/robots/panda.urdf carries the source's <collision> elements again (meshes under
robots/panda/collision/, the fingers' boxes): read by load_chain and chain_spec it still
gives both Panda models' chain.json exactly. Every link with geometry in the source is a
body (panda_link0..7, panda_hand, both fingers), the hand and fingers moving with joint
7; the robot file names the SRDF, whose disable_collisions all name those bodies. A
models directory outside the repository gets the SRDF and meshes with the URDF.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from service.manifest import REPO_MODELS_DIR, ChainSpec
from training.collision.geometry import read_bodies
from training.collision.pairs import srdf_pairs
from training.kinematics import chain_spec, load_chain
from training.robots import robot_spec
from training.train_command import robot_in

PANDA_URDF = REPO_MODELS_DIR / "robots" / "panda.urdf"


@pytest.mark.parametrize("model", ["panda-pose", "panda-position"])
def test_the_panda_chain_is_the_models_chain_json(model: str) -> None:
    """load_chain + chain_spec on the URDF with geometry == the model's chain.json."""
    expected = ChainSpec.model_validate_json((REPO_MODELS_DIR / model / "chain.json").read_bytes())
    assert chain_spec(load_chain(PANDA_URDF, "panda_hand_tcp", "panda_link0")) == expected


def test_the_panda_bodies_and_srdf() -> None:
    """Eleven bodies in their frames; the SRDF's 35 disable_collisions name bodies only."""
    chain = ChainSpec.model_validate_json((REPO_MODELS_DIR / "panda-pose/chain.json").read_bytes())
    bodies = read_bodies(PANDA_URDF, chain)
    assert [(b.link, b.frame) for b in bodies] == [
        *((f"panda_link{k}", k) for k in range(8)),
        ("panda_hand", 7), ("panda_leftfinger", 7), ("panda_rightfinger", 7),
    ]  # fmt: skip
    assert [len(b.shapes) for b in bodies] == [1] * 9 + [4, 4]
    robot = robot_spec("panda")
    assert robot.srdf == "robots/panda.srdf"
    assert len(srdf_pairs(REPO_MODELS_DIR / robot.srdf, bodies)) == 35


def test_a_models_directory_elsewhere_gets_the_pandas_srdf_and_meshes(tmp_path: Path) -> None:
    """robot_in copies the robot file, URDF, SRDF and collision meshes to another models
    directory, where the bodies read the same as in the repository's."""
    robot = robot_in(tmp_path, "panda")
    assert robot.srdf is not None and (tmp_path / robot.srdf).is_file()
    chain = ChainSpec.model_validate_json((REPO_MODELS_DIR / "panda-pose/chain.json").read_bytes())
    there = read_bodies(tmp_path / robot.urdf, chain)
    here = read_bodies(PANDA_URDF, chain)
    assert [s.mesh_path.read_bytes() for b in there for s in b.shapes if s.mesh_path] == [
        s.mesh_path.read_bytes() for b in here for s in b.shapes if s.mesh_path
    ]
    assert all(
        s.mesh_path is None or s.mesh_path.is_relative_to(tmp_path) for b in there for s in b.shapes
    )
