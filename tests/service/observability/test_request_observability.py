"""Observability: request ids, JSON access logs and Prometheus metrics of what was served.

Every response carries X-Request-ID (the client's own when sane, else a fresh one), the
access log line of the request carries the same id as JSON, and /metrics counts the
request by route, model and status, times each pipeline stage per model, and records
the accepted-sample ratio, all agreeing with the answer's own counts.
"""

from __future__ import annotations

import io
import json
import logging
import re

from fastapi.testclient import TestClient

from service.observability.logs import LOGGER_NAME, REQUEST_ID, JsonFormatter
from service.pipeline.types import TIMED_SPANS
from tests.support.metrics import metric

BODY = {
    "robot": "planar3r",
    "task": "position",
    "target": {"position": [0.5, 0.0]},
    "num_samples": 400,
}


def test_request_ids_are_echoed_generated_or_replaced(client: TestClient) -> None:
    assert (
        client.get("/healthz", headers={"X-Request-ID": "planner-7.step:42"}).headers[
            "x-request-id"
        ]
        == "planner-7.step:42"
    )
    fresh = client.get("/healthz").headers["x-request-id"]
    assert re.fullmatch(r"[0-9a-f]{32}", fresh)
    insane = client.get("/healthz", headers={"X-Request-ID": "a b\tc" + "x" * 200}).headers
    assert re.fullmatch(r"[0-9a-f]{32}", insane["x-request-id"])
    refused = client.post("/smm", json={"robot": "planar3r"}, headers={"X-Request-ID": "bad-1"})
    assert refused.status_code == 422 and refused.headers["x-request-id"] == "bad-1"


def test_access_log_lines_are_json_with_the_request_id(client: TestClient) -> None:
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.setFormatter(JsonFormatter())
    logger = logging.getLogger(LOGGER_NAME)
    logger.addHandler(handler)
    try:
        client.post("/smm", json={**BODY, "num_samples": 30}, headers={"X-Request-ID": "log-me-1"})
    finally:
        logger.removeHandler(handler)
    lines = [json.loads(line) for line in stream.getvalue().splitlines()]
    (access,) = [line for line in lines if line["request_id"] == "log-me-1"]
    assert access["message"] == "request" and access["status"] == 200
    assert access["route"] == "/smm" and access["model"] == "planar3r-position"
    assert access["method"] == "POST" and access["duration_ms"] > 0


def test_formatter_writes_fields_and_the_current_request_id() -> None:
    record = logging.LogRecord("smm", logging.WARNING, __file__, 1, "slow %s", ("stage",), None)
    record.fields = {"stage": "sample", "ms": 12.5}
    token = REQUEST_ID.set("abc")
    try:
        entry = json.loads(JsonFormatter().format(record))
    finally:
        REQUEST_ID.reset(token)
    assert entry["message"] == "slow stage" and entry["level"] == "warning"
    assert entry["request_id"] == "abc" and entry["stage"] == "sample" and entry["ms"] == 12.5


def test_metrics_count_what_was_served(client: TestClient) -> None:
    before = client.get("/metrics").text
    labels = {"route": "/smm", "method": "POST", "model": "planar3r-position", "status": "200"}
    try:
        served_before = metric(before, "smm_http_requests_total", **labels)
    except KeyError:
        served_before = 0.0
    answer = client.post("/smm", json=BODY).json()
    client.post("/smm", json={**BODY, "robot": "ur10"})  # a 404: no model label
    after = client.get("/metrics")
    assert after.headers["content-type"].startswith("text/plain")
    text = after.text
    assert metric(text, "smm_http_requests_total", **labels) == served_before + 1
    assert (
        metric(text, "smm_http_requests_total", route="/smm", method="POST", model="", status="404")
        >= 1
    )
    for stage in TIMED_SPANS:
        assert (
            metric(
                text,
                "smm_pipeline_stage_duration_seconds_count",
                model="planar3r-position",
                stage=stage,
            )
            >= 1
        )
    accepted = metric(text, "smm_samples_total", model="planar3r-position", outcome="accepted")
    accepted_before = 0.0
    if "smm_samples_total" in before:
        accepted_before = metric(
            before, "smm_samples_total", model="planar3r-position", outcome="accepted"
        )
    assert accepted - accepted_before == answer["counts"]["accepted"]
    assert metric(text, "smm_accepted_sample_ratio_count", model="planar3r-position") >= 1
    assert metric(text, "smm_requests_rejected_total", reason="queue_full") == 0
    assert metric(text, "smm_pipeline_in_flight") == 0
    assert metric(text, "smm_http_requests_in_flight") == 1  # this scrape itself
    assert metric(text, "smm_model_ready", model="iiwa14-pose") == 1
    assert metric(text, "process_resident_memory_bytes") > 0
