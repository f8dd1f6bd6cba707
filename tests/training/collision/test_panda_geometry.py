"""The bundled Panda's collision geometry: back in its URDF, its kinematics untouched.

models/robots/panda.urdf carries the source's <collision> elements again (meshes under
robots/panda/collision/, the fingers' boxes): read by load_chain and chain_spec it still
gives both Panda models' chain.json exactly. Every link with geometry in the source is a
body (panda_link0..7, panda_hand, both fingers), the hand and fingers moving with joint
7; the robot file names the SRDF, whose disable_collisions all name those bodies.
"""

from __future__ import annotations

import pytest

from service.manifest import REPO_MODELS_DIR, ChainSpec
from training.collision.geometry import read_bodies
from training.collision.pairs import srdf_pairs
from training.kinematics import chain_spec, load_chain
from training.robots import robot_spec

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
