"""Fixtures of the scene section's tests: the bundled panda-pose model and its coal robot,
loaded once per test run, and the small collision arm's chain."""

from __future__ import annotations

from pathlib import Path

import pytest

from service.manifest import REPO_MODELS_DIR, ChainSpec
from service.models.registry import ServedModel, load_model
from tests.support.collision_arm import BASE, END_EFFECTOR, write_collision_arm
from training.evaluate.scenes.coal_model import CoalModel
from training.kinematics import chain_spec, load_chain


@pytest.fixture(scope="session")
def panda_pose_model() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "panda-pose", threads=0)


@pytest.fixture(scope="session")
def panda_coal(panda_pose_model: ServedModel) -> CoalModel:
    return CoalModel.of(panda_pose_model)


@pytest.fixture(scope="module")
def arm_chain(tmp_path_factory: pytest.TempPathFactory) -> ChainSpec:
    urdf: Path = write_collision_arm(tmp_path_factory.mktemp("arm"))
    return chain_spec(load_chain(urdf, END_EFFECTOR, BASE))
