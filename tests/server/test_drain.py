"""Shutdown drains: on SIGTERM a request in flight still gets its answer, then the process exits 0.

A real server computing a slow request (iiwa14 pose, 4000 samples) gets SIGTERM; the
request must complete with 200 and a full answer, new connections must be refused
meanwhile, and the process must exit by itself once it is done, through the app's
shutdown (its "shut down" log line). uvicorn re-raises the SIGTERM after a graceful
shutdown, so the exit status is -SIGTERM (or 0), never a kill.
"""

from __future__ import annotations

import signal
import threading
import time

import httpx
import pytest

from tests.support.bodies import POSE
from tests.support.metrics import metric
from tools.local_server import LocalServer

SLOW = {**POSE, "num_samples": 4000}


def test_sigterm_lets_the_request_in_flight_finish() -> None:
    server = LocalServer().start()
    try:
        answers: list[httpx.Response] = []
        request = threading.Thread(
            target=lambda: answers.append(httpx.post(f"{server.url}/smm", json=SLOW, timeout=120))
        )
        request.start()
        deadline = time.monotonic() + 30
        while metric(httpx.get(f"{server.url}/metrics").text, "smm_pipeline_in_flight") < 1:
            assert time.monotonic() < deadline, "the slow request never started computing"
            time.sleep(0.02)
        server.terminate()
        time.sleep(0.3)
        with pytest.raises(httpx.TransportError):  # no new connections while draining
            httpx.get(f"{server.url}/healthz", timeout=2)
        request.join(timeout=120)
        assert server.wait(timeout_s=60) in (0, -signal.SIGTERM)
    finally:
        server.stop()
    (answer,) = answers
    assert answer.status_code == 200
    assert answer.json()["counts"]["sampled"] == 4000
    assert any(line.get("message") == "shut down" for line in server.log_lines())
