"""client: the retry policy, the errors and the request bodies, against a scripted transport.

No server here (tests/server/test_client.py runs the client against a real one): an
httpx.MockTransport answers from a script, and the client's sleep is a recorder, so each
test checks exactly which attempts were made and how long the client waited between
them. Checked: a 503 with Retry-After is retried after exactly that wait, within the
attempts allowed; a 503 without one, a Retry-After above the cap and every other error
status are not; a connection error is retried with doubling backoff and then raised as
SmmConnectionError; a read timeout is raised as SmmTimeoutError at once; a 422 carries
each field's location and the server's message; the body sent is the request model's
JSON without nulls, with the API key header; a batch is asked for as NDJSON lines and
read back into its response, and lines cut off before their end raise
SmmConnectionError; a connection dropped while an answer's body is read is retried as
one dropped before it.
"""

from __future__ import annotations

import json
from collections.abc import Iterator

import httpx
import pytest

from service.client import (
    BatchTargetIn,
    FieldError,
    RetryEvent,
    RetryPolicy,
    SmmBatchRequest,
    SmmClient,
    SmmConnectionError,
    SmmHTTPError,
    SmmRequest,
    SmmTimeoutError,
    TargetIn,
)
from service.client.retry import parse_retry_after_s

PLANAR = SmmRequest(robot="planar3r", task="position", target=TargetIn(position=[0.5, 0.0]))
LIVE = {"status": "alive"}

Step = httpx.Response | Exception


class Script:
    """A transport that answers each request with the next step of a script."""

    def __init__(self, *steps: Step) -> None:
        self.steps: Iterator[Step] = iter(steps)
        self.requests: list[httpx.Request] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.requests.append(request)
        step = next(self.steps)
        if isinstance(step, Exception):
            raise step
        return step


def make(
    script: Script, retry: RetryPolicy | None = None, api_key: str | None = None
) -> tuple[SmmClient, list[float], list[RetryEvent]]:
    waits: list[float] = []
    events: list[RetryEvent] = []
    client = SmmClient(
        "http://smm.test",
        api_key=api_key,
        retry=retry,
        transport=httpx.MockTransport(script),
        sleep=waits.append,
        on_retry=events.append,
    )
    return client, waits, events


def busy(retry_after: str | None = "2") -> httpx.Response:
    headers = {} if retry_after is None else {"Retry-After": retry_after}
    return httpx.Response(503, json={"detail": "server at capacity"}, headers=headers)


def test_a_503_with_retry_after_is_retried_after_exactly_that_wait() -> None:
    script = Script(busy("2"), busy("1"), httpx.Response(200, json=LIVE))
    client, waits, events = make(script)
    assert client.healthz().status == "alive"
    assert len(script.requests) == 3
    assert waits == [2.0, 1.0]
    assert [(e.attempt, e.reason) for e in events] == [
        (1, "503 Retry-After: 2"),
        (2, "503 Retry-After: 1"),
    ]


def test_retries_are_bounded_and_the_last_503_is_raised_with_its_message() -> None:
    script = Script(*[busy("1")] * 3)
    client, waits, _ = make(script, retry=RetryPolicy(max_attempts=3))
    with pytest.raises(SmmHTTPError) as raised:
        client.smm(PLANAR)
    assert len(script.requests) == 3 and waits == [1.0, 1.0]
    assert raised.value.status_code == 503
    assert raised.value.detail == "server at capacity"
    assert raised.value.retry_after_s == 1.0


@pytest.mark.parametrize(
    "answer",
    [
        busy(None),  # a model that failed verification: retrying cannot help
        busy("120"),  # longer than max_retry_after_s: raised at once, not waited for
        httpx.Response(500, text="Internal Server Error"),
        httpx.Response(404, json={"detail": "unknown robot 'x'; served: planar3r"}),
    ],
)
def test_other_errors_are_not_retried(answer: httpx.Response) -> None:
    script = Script(answer)
    client, waits, _ = make(script)
    with pytest.raises(SmmHTTPError) as raised:
        client.smm(PLANAR)
    assert len(script.requests) == 1 and waits == []
    assert raised.value.status_code == answer.status_code
    assert raised.value.detail  # the server's words, or its text when it sent no JSON


def test_connection_errors_are_retried_with_doubling_backoff_then_raised() -> None:
    refused = httpx.ConnectError("connection refused")
    script = Script(refused, httpx.RemoteProtocolError("dropped"), refused, refused)
    client, waits, events = make(script, retry=RetryPolicy(max_attempts=4, backoff_s=0.5))
    with pytest.raises(SmmConnectionError, match="after 4 attempt"):
        client.smm(PLANAR)
    assert waits == [0.5, 1.0, 2.0]
    assert [e.reason for e in events] == ["ConnectError", "RemoteProtocolError", "ConnectError"]


def test_a_read_timeout_raises_at_once() -> None:
    script = Script(httpx.ReadTimeout("timed out"))
    client, waits, _ = make(script)
    with pytest.raises(SmmTimeoutError, match="within the timeout"):
        client.smm(PLANAR, timeout=0.5)
    assert len(script.requests) == 1 and waits == []
    assert script.requests[0].extensions["timeout"]["read"] == 0.5  # the per-call timeout


def test_a_422_carries_each_field_location_and_the_server_message() -> None:
    position = "targets[1].target.position must have 2 values (x, y), got 3"
    detail = [
        {
            "loc": ["body", "targets", 1, "target", "position"],
            "msg": position,
            "type": "value_error",
        },
        {"loc": ["body", "seed"], "msg": "seed: must be >= 0", "type": "greater_than_equal"},
    ]
    script = Script(httpx.Response(422, json={"detail": detail}, headers={"X-Request-ID": "r1"}))
    client, _, _ = make(script)
    with pytest.raises(SmmHTTPError) as raised:
        client.smm(PLANAR)
    error = raised.value
    assert error.status_code == 422 and error.request_id == "r1"
    assert error.field_errors == [
        FieldError(("body", "targets", 1, "target", "position"), position, "value_error"),
        FieldError(("body", "seed"), "seed: must be >= 0", "greater_than_equal"),
    ]
    assert [e.field for e in error.field_errors] == ["targets[1].target.position", "seed"]
    assert error.detail == f"{position}; seed: must be >= 0"
    assert "POST /smm -> 422" in str(error) and "r1" in str(error)


def test_the_body_is_the_request_model_without_nulls_and_the_key_is_sent() -> None:
    script = Script(httpx.Response(401, json={"detail": "missing or wrong API key"}))
    client, _, _ = make(script, api_key="k3y")
    with pytest.raises(SmmHTTPError):
        client.smm(PLANAR)
    sent = script.requests[0]
    assert sent.headers["X-API-Key"] == "k3y"
    assert sent.headers["Content-Type"] == "application/json"
    assert json.loads(sent.content) == {
        "robot": "planar3r",
        "task": "position",
        "target": {"position": [0.5, 0.0]},
        "seed": 0,
        "tolerance": {},
        "include_paths": True,
        "include_roadmap": False,
        "obstacles": [],
        "collision": {"self": True, "margin_m": 0.0},
    }


def test_retry_after_reads_seconds_and_http_dates() -> None:
    assert parse_retry_after_s("3") == 3.0
    assert parse_retry_after_s("Wed, 21 Oct 2015 07:28:05 GMT", now_s=1445412480.0) == 5.0
    assert parse_retry_after_s("soon") is None
    assert parse_retry_after_s(None) is None
    with pytest.raises(ValueError, match="max_attempts"):
        RetryPolicy(max_attempts=0)


HEAD: dict[str, object] = {
    "robot": "planar3r",
    "task": "position",
    "model": "planar3r-position@0",
    "joint_names": ["a", "b", "c"],
    "redundancy": 1,
}
MISSED: dict[str, object] = {"index": 0, "status": "deadline_exceeded", "answer": None}
END: dict[str, object] = {"status": "partial", "timings_ms": {"total": 3.0}}
BATCH = SmmBatchRequest(
    robot="planar3r", task="position", targets=[BatchTargetIn(target=PLANAR.target)]
)


def ndjson(*lines: dict[str, object]) -> httpx.Response:
    body = b"".join(json.dumps(line).encode() + b"\n" for line in lines)
    return httpx.Response(200, content=body, headers={"Content-Type": "application/x-ndjson"})


def test_a_batch_is_asked_as_lines_and_read_back_into_the_response() -> None:
    script = Script(busy("1"), ndjson(HEAD, MISSED, END))
    client, waits, _ = make(script)
    answer = client.smm_batch(BATCH)
    assert waits == [1.0]  # a 503 before the lines is retried as any other
    assert script.requests[-1].headers["accept"] == "application/x-ndjson"
    assert answer.model_dump(mode="json") == {**HEAD, **END, "results": [MISSED]}


@pytest.mark.parametrize("lines", [(HEAD, MISSED), (HEAD,), ()])
def test_lines_cut_off_before_the_end_raise_a_connection_error(
    lines: tuple[dict[str, object], ...],
) -> None:
    client, _, _ = make(Script(ndjson(*lines)))
    with pytest.raises(SmmConnectionError, match="stopped before its last line"):
        client.smm_batch(BATCH)


class DroppedBody(httpx.SyncByteStream):
    """A body whose connection drops after its first bytes."""

    def __iter__(self) -> Iterator[bytes]:
        yield b'{"status": '
        raise httpx.ReadError("connection reset while reading the body")


def test_a_connection_dropped_while_reading_the_answer_is_retried() -> None:
    script = Script(httpx.Response(200, stream=DroppedBody()), httpx.Response(200, json=LIVE))
    client, waits, events = make(script)
    assert client.healthz().status == "alive"
    assert len(script.requests) == 2 and waits == [0.5]
    assert [e.reason for e in events] == ["ReadError"]
