"""The small collision arm, written once per module, and its chain as chain.json holds it."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.manifest import ChainSpec, JointSpec
from tests.support.collision_arm import BASE, END_EFFECTOR, write_collision_arm
from training.kinematics import chain_spec, joint_spec, load_chain


@pytest.fixture(scope="module")
def arm_urdf(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_collision_arm(tmp_path_factory.mktemp("arm"))


@pytest.fixture(scope="module")
def arm_chain(arm_urdf: Path) -> ChainSpec:
    return chain_spec(load_chain(arm_urdf, END_EFFECTOR, BASE))


@pytest.fixture(scope="module")
def arm_joints(arm_urdf: Path) -> JointSpec:
    return joint_spec(load_chain(arm_urdf, END_EFFECTOR, BASE))
