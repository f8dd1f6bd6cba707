"""Fixtures of the docs tests: one real server with the bundled models, which the
documented commands and HTTP examples are run against."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tools.local_server import LocalServer


@pytest.fixture(scope="package")
def server() -> Iterator[LocalServer]:
    with LocalServer() as running:
        yield running
