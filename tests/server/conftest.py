"""Real-server fixtures: the service as a uvicorn process on 127.0.0.1 with the bundled models.

`server` is shared by the tests of a module that only send requests; a test that
overloads, soaks or stops a server starts its own with `LocalServer`.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tools.local_server import LocalServer

# Small enough that fuzzed requests which reach the pipeline stay quick.
FUZZ_MAX_NUM_SAMPLES = 200
FUZZ_MAX_BATCH_TARGETS = 4


@pytest.fixture(scope="module")
def server() -> Iterator[LocalServer]:
    with LocalServer(
        max_num_samples=FUZZ_MAX_NUM_SAMPLES,
        max_batch_targets=FUZZ_MAX_BATCH_TARGETS,
        max_batch_samples=FUZZ_MAX_BATCH_TARGETS * FUZZ_MAX_NUM_SAMPLES,
    ) as running:
        yield running
