"""The Python client (`service.client`) against real servers on 127.0.0.1.

One server with an API key answers the client's calls: a real POST /smm answer parsed
into the typed model dumps back to exactly the raw JSON (so the models drop nothing),
and the client's answer equals the raw one but for the timings; the same for a batch,
whose each answer also equals the client's POST /smm of that target; a 422 carries the
server's own field location and message; a 404 the served list; a wrong key gets the
server's 401 message, unretried; the probes and GET /robots parse.

A second server has room for one computation and none waiting: while a long batch holds
the slot, a POST /smm gets a real 503 with Retry-After: 1. Without retries the client
raises it with the server's message; with them it waits the Retry-After between
attempts (measured loosely: each gap at least 0.9 s) and returns the answer once the slot
is free. A per-call timeout shorter than the computation raises SmmTimeoutError, and a
port nobody listens on raises SmmConnectionError after the bounded attempts.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from service.client import (
    BatchTargetIn,
    QuaternionIn,
    RetryEvent,
    RetryPolicy,
    SmmBatchRequest,
    SmmClient,
    SmmConnectionError,
    SmmHTTPError,
    SmmRequest,
    SmmResponse,
    SmmTimeoutError,
    TargetIn,
)
from service.http.auth import UNAUTHORIZED_MESSAGE
from service.wire import SmmBatchResponse
from tests.support.metrics import metric
from tools.local_server import LocalServer, free_port

KEY = "client-test-key"
POSE = SmmRequest(
    robot="iiwa14",
    task="pose",
    target=TargetIn(
        position=[0.6501, 0.2011, 0.5018],
        orientation=QuaternionIn(w=0.2165, x=-0.1458, y=0.9648, z=0.0327),
    ),
    num_samples=300,
    seed=3,
    reference_configuration=[0.3, 0.6, 0.0, -1.2, 0.0, 0.9, 0.0],
    max_configurations_per_component=5,
)
PLANAR = SmmRequest(robot="planar3r", task="position", target=TargetIn(position=[1.2, 0.4]))


def without_timings(answer: dict[str, object]) -> dict[str, object]:
    return {k: v for k, v in answer.items() if k != "timings_ms"}


@pytest.fixture(scope="module")
def keyed() -> Iterator[LocalServer]:
    with LocalServer(api_key=KEY) as running:
        yield running


@pytest.fixture()
def client(keyed: LocalServer) -> Iterator[SmmClient]:
    with SmmClient(keyed.url, api_key=KEY) as smm:
        yield smm


def raw_post(server: LocalServer, path: str, body: dict[str, object]) -> httpx.Response:
    response = httpx.post(server.url + path, json=body, headers={"X-API-Key": KEY}, timeout=60)
    assert response.status_code == 200, response.text
    return response


def test_a_real_answer_parses_into_the_model_and_back_to_the_same_json(
    keyed: LocalServer, client: SmmClient
) -> None:
    raw = raw_post(keyed, "/smm", POSE.model_dump(mode="json", exclude_none=True))
    assert SmmResponse.model_validate_json(raw.content).model_dump(mode="json") == raw.json()

    answer = client.smm(POSE)
    assert isinstance(answer, SmmResponse) and answer.status == "ok"
    assert len(answer.components) > 1 and answer.components[0].path  # r = 1: ordered paths
    assert without_timings(answer.model_dump(mode="json")) == without_timings(raw.json())


def test_the_batch_answers_each_target_as_the_client_smm_does(
    keyed: LocalServer, client: SmmClient
) -> None:
    batch = SmmBatchRequest(
        robot="planar3r",
        task="position",
        num_samples=200,
        max_configurations_per_component=3,
        targets=[
            BatchTargetIn(target=TargetIn(position=[0.5, 0.0])),
            BatchTargetIn(target=TargetIn(position=[0.5, 0.2]), seed=4),
            BatchTargetIn(target=TargetIn(position=[3.5, 0.0])),
        ],
    )
    raw = raw_post(keyed, "/smm/batch", batch.model_dump(mode="json", exclude_none=True))
    assert SmmBatchResponse.model_validate_json(raw.content).model_dump(mode="json") == raw.json()

    answer = client.smm_batch(batch)  # read as NDJSON lines: the same answer
    assert answer.status == "complete"
    assert [r.status for r in answer.results] == ["ok", "ok", "no_solution"]
    for index, result in enumerate(answer.results):
        assert result.answer is not None
        single = client.smm(batch.request_for(index))
        assert without_timings(result.answer.model_dump()) == without_timings(single.model_dump())
    assert without_answer_timings(answer.model_dump(mode="json")) == without_answer_timings(
        raw.json()
    )
    handed = [r.model_dump(mode="json") for r in client.smm_batch_results(batch)]
    assert without_answer_timings({"results": handed}) == without_answer_timings(
        {"results": raw.json()["results"]}
    )


def without_answer_timings(batch: dict[str, Any]) -> dict[str, Any]:
    """A batch's JSON without the batch's timings or any answer's."""
    results = [
        {**r, "answer": r["answer"] and without_timings(r["answer"])} for r in batch["results"]
    ]
    return {**without_timings(batch), "results": results}


def test_leaving_the_batchs_lines_early_frees_the_slot() -> None:
    """The client stops reading after the first target: the server stops the batch (the
    targets under way finish) and frees its slot, long before the 32 targets are answered."""
    targets = [BatchTargetIn(target=POSE.target, seed=seed) for seed in range(32)]
    long_batch = LONG_BATCH.model_copy(update={"targets": targets})
    with LocalServer(max_in_flight=1, max_queued=0) as server:
        with SmmClient(server.url) as smm:
            first = next(iter(smm.smm_batch_results(long_batch)))
            assert first.index == 0 and first.status == "ok"
        deadline = time.monotonic() + 60
        while metric(httpx.get(server.url + "/metrics").text, "smm_pipeline_in_flight") > 0:
            assert time.monotonic() < deadline, "the batch kept its slot"
            time.sleep(0.02)
        exposition = httpx.get(server.url + "/metrics").text
        answered = metric(
            exposition,
            "smm_pipeline_stage_duration_seconds_count",
            model="iiwa14-pose",
            stage="total",
        )
        assert 1 <= answered < 8, answered  # stopped within a few targets, not all 32
        assert server.log_lines() and not [
            line for line in server.log_lines() if line.get("level") == "error"
        ]


def test_a_422_carries_the_servers_field_and_message(client: SmmClient) -> None:
    # Valid for the wire model (1 to 3 values), wrong for this robot: the server says so.
    body = SmmRequest(robot="planar3r", task="position", target=TargetIn(position=[0.5, 0, 0.2]))
    with pytest.raises(SmmHTTPError) as raised:
        client.smm(body)
    error = raised.value
    assert error.status_code == 422
    message = "target.position must have 2 values (x, y) for the position task of this robot, got 3"
    assert [(e.loc, e.msg) for e in error.field_errors] == [
        (("body", "target", "position"), message)
    ]
    assert error.field_errors[0].field == "target.position"
    assert error.detail == message and error.request_id


def test_a_404_lists_what_is_served(client: SmmClient) -> None:
    with pytest.raises(SmmHTTPError) as raised:
        client.smm(PLANAR.model_copy(update={"robot": "ur10"}))
    assert raised.value.status_code == 404
    assert "ur10" in raised.value.detail and "iiwa14" in raised.value.detail


def test_a_wrong_key_gets_the_servers_401_unretried(keyed: LocalServer) -> None:
    events: list[RetryEvent] = []
    with SmmClient(keyed.url, api_key="wrong", on_retry=events.append) as smm:
        with pytest.raises(SmmHTTPError) as raised:
            smm.robots()
        assert smm.healthz().status == "alive"  # the probes are open
    assert raised.value.status_code == 401
    assert raised.value.detail == UNAUTHORIZED_MESSAGE
    assert events == []


def test_probes_and_robots(client: SmmClient) -> None:
    assert client.healthz().status == "alive"
    assert client.is_ready()
    assert {"iiwa14-pose", "planar3r-position"} <= {
        reference.split("@")[0] for reference in client.readyz().models
    }
    iiwa = client.robot("iiwa14", "pose")
    assert iiwa.joint_names[0] == "joint1" and len(iiwa.joint_lower) == 7
    with pytest.raises(LookupError, match="served: "):
        client.robot("iiwa14", "dance")


# -- overload, timeout, no server ------------------------------------------------------

LONG_BATCH = SmmBatchRequest(
    robot="iiwa14",
    task="pose",
    num_samples=2000,
    include_paths=False,
    targets=[BatchTargetIn(target=POSE.target, seed=seed) for seed in range(4)],
)


def test_a_real_503_is_retried_after_its_retry_after() -> None:
    with LocalServer(max_in_flight=1, max_queued=0, retry_after_s=1) as server:
        holder = threading.Thread(
            target=lambda: httpx.post(
                server.url + "/smm/batch",
                json=LONG_BATCH.model_dump(mode="json", exclude_none=True),
                timeout=120,
            )
        )
        holder.start()
        try:
            deadline = time.monotonic() + 30
            while metric(httpx.get(server.url + "/metrics").text, "smm_pipeline_in_flight") < 1:
                assert time.monotonic() < deadline, "the long batch never took the slot"
                time.sleep(0.02)

            once = SmmClient(server.url, retry=RetryPolicy(max_attempts=1))
            with once, pytest.raises(SmmHTTPError) as raised:
                once.smm(PLANAR)
            assert raised.value.status_code == 503 and raised.value.retry_after_s == 1.0
            assert "server at capacity" in raised.value.detail

            sent: list[float] = []
            events: list[RetryEvent] = []
            with SmmClient(
                server.url, retry=RetryPolicy(max_attempts=60), on_retry=events.append
            ) as patient:
                patient.http.event_hooks["request"].append(lambda _: sent.append(time.monotonic()))
                answer = patient.smm(PLANAR)
        finally:
            holder.join()
    assert answer.status == "ok"
    assert events, "the long batch should still hold the slot at the first attempt"
    assert {(e.wait_s, e.reason) for e in events} == {(1.0, "503 Retry-After: 1")}
    assert len(sent) == len(events) + 1
    gaps = [b - a for a, b in itertools.pairwise(sent)]
    print(f"client: {len(events)} retries after 503, gaps {[round(g, 3) for g in gaps]} s")
    assert all(gap >= 0.9 for gap in gaps), gaps  # it waited what Retry-After said


def test_a_timeout_raises_a_clear_error(client: SmmClient) -> None:
    with pytest.raises(SmmTimeoutError, match=r"POST /smm: no answer .* within the timeout"):
        client.smm(POSE, timeout=0.005)


def test_no_server_raises_a_connection_error_after_the_bounded_attempts() -> None:
    events: list[RetryEvent] = []
    url = f"http://127.0.0.1:{free_port()}"
    retry = RetryPolicy(max_attempts=3, backoff_s=0.01)
    smm = SmmClient(url, retry=retry, on_retry=events.append)
    with smm, pytest.raises(SmmConnectionError, match="after 3 attempt"):
        smm.healthz()
    assert [e.reason for e in events] == ["ConnectError", "ConnectError"]
