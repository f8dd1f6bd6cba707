"""Fixtures of the evaluation tests: the bundled iiwa14 models, loaded once per session."""

from __future__ import annotations

import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model


@pytest.fixture(scope="session")
def iiwa14_pose_model() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=0)


@pytest.fixture(scope="session")
def iiwa14_position_model() -> ServedModel:
    return load_model(REPO_MODELS_DIR / "iiwa14-position", threads=0)
