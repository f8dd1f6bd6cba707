"""Shared fixtures: the bundled planar 3R model and an HTTP client on the real app."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from tests.support.app import PLANAR3R_DIR, make_client


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    # A run that collects no tests must fail (pytest's own exit code 5 already does;
    # this keeps it so under any plugin that rewrites exit codes).
    if session.testscollected == 0:
        session.exitstatus = pytest.ExitCode.NO_TESTS_COLLECTED


@pytest.fixture(scope="session")
def planar3r() -> ServedModel:
    return load_model(PLANAR3R_DIR, threads=0)


@pytest.fixture(scope="session")
def client() -> Iterator[TestClient]:
    with make_client(REPO_MODELS_DIR, max_num_samples=5000) as test_client:
        yield test_client
