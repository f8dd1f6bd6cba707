"""The flow-threads benchmark (`python -m tools.onnx_threads`): it times the served
network on one thread, on the service's threads and (an int8 network, where AMX, VNNI or
AVX2 is usable) on the compiled layers at each row count asked, and marks the row counts the
service runs on every thread as `sessions.PARALLEL_MIN_ROWS` says."""

from __future__ import annotations

import math

from service.manifest import FLOW_INT8_FILE
from service.models.registry import int8_on_compiled_layers
from service.models.sessions import PARALLEL_MIN_ROWS
from tools.onnx_threads import measure


def test_each_row_count_is_timed_on_both_sessions_and_marked_as_served() -> None:
    rows = [PARALLEL_MIN_ROWS - 1, PARALLEL_MIN_ROWS]
    results = measure("planar3r-position", rows, threads=2, rounds=1, calls=1)
    assert [r["rows"] for r in results] == rows
    assert all(r["network"] == FLOW_INT8_FILE for r in results)  # the served sampler's
    for r in results:
        for key in ("one_thread_ms", "service_threads_ms"):
            assert math.isfinite(r[key]) and r[key] > 0
        assert r["served_compiled"] is int8_on_compiled_layers()
        assert (r["compiled_ms"] is not None) is int8_on_compiled_layers()
    assert [r["served_on_every_thread"] for r in results] == [False, True]
