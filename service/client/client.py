"""`SmmClient`: the service's HTTP API as typed Python calls (httpx, synchronous).

Requests and answers are the server's own wire models (`service.wire`): a body is
validated by the same pydantic model the server validates it with before it is sent, and
an answer is parsed into the model the server built it from.

    with SmmClient("http://127.0.0.1:8000", api_key="...") as smm:
        answer = smm.smm(SmmRequest(robot="iiwa14", task="pose", target=...))

Errors: `SmmHTTPError` (status, the server's `detail`, a 422's field errors),
`SmmTimeoutError`, `SmmConnectionError`; retries: `retry.RetryPolicy`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import TracebackType
from typing import TypeVar

import httpx
from pydantic import BaseModel

from service.client.errors import SmmConnectionError, SmmHTTPError, SmmTimeoutError
from service.client.retry import (
    RETRIED_TRANSPORT_ERRORS,
    RetryEvent,
    RetryPolicy,
    parse_retry_after_s,
)
from service.wire import (
    NDJSON,
    BatchItemOut,
    LivenessResponse,
    ReadinessResponse,
    RobotOut,
    RobotsResponse,
    SelfMotionRequest,
    SelfMotionResponse,
    SmmBatchEnd,
    SmmBatchHead,
    SmmBatchRequest,
    SmmBatchResponse,
    SmmRequest,
    SmmResponse,
)

API_KEY_HEADER = "X-API-Key"  # the header service/http/auth.py reads
REQUEST_ID_HEADER = "X-Request-ID"
# Connecting to a server that is up takes milliseconds; an answer can take seconds (the
# server's own deadline is SMM_REQUEST_DEADLINE_S, 30 s by default).
DEFAULT_TIMEOUT = httpx.Timeout(60.0, connect=5.0)

log = logging.getLogger(__name__)
Answer = TypeVar("Answer", bound=BaseModel)


class SmmClient:
    """A client of one SMM server, over one httpx.Client (its connection pool); close it
    (or use `with`).

    `base_url`: the server, e.g. "http://127.0.0.1:8000". `api_key`: sent as X-API-Key
    when the server sets SMM_API_KEY. `timeout`: seconds (or an httpx.Timeout) per
    attempt, also settable per call. `retry`: when to send a request again (see
    `RetryPolicy`). `on_retry`: called with a `RetryEvent` before each wait.
    `transport`: an httpx transport, for tests or a custom network stack. `sleep`: how
    the client waits between attempts (time.sleep; tests pass a recorder).
    """

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8000",
        *,
        api_key: str | None = None,
        timeout: float | httpx.Timeout = DEFAULT_TIMEOUT,
        retry: RetryPolicy | None = None,
        on_retry: Callable[[RetryEvent], None] | None = None,
        transport: httpx.BaseTransport | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        headers = {"User-Agent": "smm-client"}
        if api_key is not None:
            headers[API_KEY_HEADER] = api_key
        self.retry = retry or RetryPolicy()
        self.on_retry = on_retry
        self._sleep = sleep
        self.http = httpx.Client(
            base_url=base_url, headers=headers, timeout=timeout, transport=transport
        )

    # -- the API -----------------------------------------------------------------------

    def smm(self, request: SmmRequest, *, timeout: float | None = None) -> SmmResponse:
        """POST /smm: the self-motion manifolds of one target."""
        return self._call("POST", "/smm", SmmResponse, request, timeout)

    def smm_batch(
        self, request: SmmBatchRequest, *, timeout: float | None = None
    ) -> SmmBatchResponse:
        """POST /smm/batch: many targets of one model in one request, answered in order.

        Read as the server sends it, one line per target (NDJSON): each answer is parsed
        while the server computes the next, so the whole batch arrives parsed soon after
        its last target is answered (`smm_batch_results` hands each over as it comes)."""
        head: SmmBatchHead | None = None
        results: list[BatchItemOut] = []
        for line in self._batch_lines(request, timeout):
            if isinstance(line, SmmBatchHead):
                head = line
            elif isinstance(line, BatchItemOut):
                results.append(line)
            else:
                assert head is not None, "the head comes first"
                return SmmBatchResponse.of_lines(head, results, line)
        raise AssertionError("_batch_lines ends with the SmmBatchEnd")

    def smm_batch_results(
        self, request: SmmBatchRequest, *, timeout: float | None = None
    ) -> Iterator[BatchItemOut]:
        """POST /smm/batch, each target's result handed over as soon as the server has
        answered it (and those before it), in order; a planner can act on the first
        targets while the server computes the rest. Leaving the loop early stops the
        server's computation of the rest. `timeout` bounds the wait for each line."""
        for line in self._batch_lines(request, timeout):
            if isinstance(line, BatchItemOut):
                yield line

    def self_motion(
        self, request: SelfMotionRequest, *, timeout: float | None = None
    ) -> SelfMotionResponse:
        """POST /smm/self-motion: a path along the self-motion manifold from a start to a
        goal configuration or objective, or the components that keep them apart."""
        return self._call("POST", "/smm/self-motion", SelfMotionResponse, request, timeout)

    def robots(self) -> list[RobotOut]:
        """GET /robots: every served model with its manifest facts (joint names, limits,
        periodicity, defaults)."""
        return self._call("GET", "/robots", RobotsResponse, None, None).models

    def robot(self, robot: str, task: str) -> RobotOut:
        """The served model of `robot` and `task`, from GET /robots; LookupError, listing
        what is served, when there is none."""
        models = self.robots()
        for model in models:
            if model.robot == robot and model.task == task:
                return model
        served = ", ".join(f"{m.robot}/{m.task}" for m in models) or "nothing"
        raise LookupError(f"no model for robot {robot!r}, task {task!r}; served: {served}")

    def healthz(self) -> LivenessResponse:
        """GET /healthz: the process is alive (open without the API key)."""
        return self._call("GET", "/healthz", LivenessResponse, None, None)

    def readyz(self) -> ReadinessResponse:
        """GET /readyz: the readiness report, also when it is not ready (its 503 is an
        answer here, not an error, and is not retried)."""
        response = self._send("GET", "/readyz", None, None)
        if response.status_code in (200, 503):
            return ReadinessResponse.model_validate_json(response.content)
        raise self._error("GET", "/readyz", response)

    def is_ready(self) -> bool:
        """True when every model is loaded and verified and the server is not draining."""
        return self.readyz().status == "ready"

    # -- plumbing ----------------------------------------------------------------------

    def _batch_lines(
        self, request: SmmBatchRequest, timeout: float | None
    ) -> Iterator[SmmBatchHead | BatchItemOut | SmmBatchEnd]:
        """POST /smm/batch's NDJSON lines, parsed as each arrives: the head, one item per
        target, the end. SmmConnectionError when the stream stops before its end."""
        path = "/smm/batch"
        with self._open("POST", path, request, timeout, accept=NDJSON) as response:
            if response.status_code != 200:
                response.read()
                raise self._error("POST", path, response)
            lines = response.iter_lines()
            try:
                yield SmmBatchHead.model_validate_json(next(lines))
                for line in lines:
                    if line.startswith('{"index"'):  # an item (the server writes index first)
                        yield BatchItemOut.model_validate_json(line)
                    else:
                        yield SmmBatchEnd.model_validate_json(line)
                        return
            except httpx.TimeoutException:
                raise  # SmmTimeoutError, from _open
            except (StopIteration, httpx.TransportError) as error:
                cause = f": {type(error).__name__}: {error}" if str(error) else ""
                raise self._cut_off(path, cause) from error
            raise self._cut_off(path)

    def _cut_off(self, path: str, cause: str = "") -> SmmConnectionError:
        return SmmConnectionError(
            f"POST {path}: the answer from {self.http.base_url} stopped before its last line{cause}"
        )

    def _call(
        self,
        method: str,
        path: str,
        answer: type[Answer],
        body: BaseModel | None,
        timeout: float | None,
    ) -> Answer:
        response = self._send(method, path, body, timeout)
        if response.status_code != 200:
            raise self._error(method, path, response)
        return answer.model_validate_json(response.content)

    def _send(
        self, method: str, path: str, body: BaseModel | None, timeout: float | None
    ) -> httpx.Response:
        """One request, sent again as the retry policy allows; the last answer, whatever
        its status, or SmmTimeoutError / SmmConnectionError."""
        with self._open(method, path, body, timeout, streamed=False) as response:
            return response

    @contextmanager
    def _open(
        self,
        method: str,
        path: str,
        body: BaseModel | None,
        timeout: float | None,
        accept: str | None = None,
        streamed: bool = True,
    ) -> Iterator[httpx.Response]:
        """`_send`, with the answer's body left to read from the response while it
        arrives (closed when the block ends); `streamed` False: read whole first, a
        connection dropped while reading it retried as one dropped before it."""
        # Absent and null mean the same in the contract; absent keeps the body small.
        content = None if body is None else body.model_dump_json(exclude_none=True).encode()
        headers = {"Content-Type": "application/json"} if content is not None else {}
        if accept is not None:
            headers["Accept"] = accept
        per_call = httpx.USE_CLIENT_DEFAULT if timeout is None else httpx.Timeout(timeout)
        attempt = 0
        while True:
            attempt += 1
            outgoing = self.http.build_request(
                method, path, content=content, headers=headers, timeout=per_call
            )
            try:
                response = self.http.send(outgoing, stream=streamed)
            except RETRIED_TRANSPORT_ERRORS as error:
                if attempt >= self.retry.max_attempts:
                    raise SmmConnectionError(
                        f"{method} {path}: no answer from {self.http.base_url} after "
                        f"{attempt} attempt(s): {type(error).__name__}: {error}"
                    ) from error
                wait_s = self.retry.wait_after_transport_error_s(attempt)
                self._before_retry(method, path, attempt, wait_s, type(error).__name__)
                continue
            except httpx.TimeoutException as error:
                raise _timeout(method, path, self.http.base_url, error) from error
            except httpx.TransportError as error:
                raise SmmConnectionError(
                    f"{method} {path}: {type(error).__name__}: {error}"
                ) from error
            try:
                wait = None
                if response.status_code == 503 and attempt < self.retry.max_attempts:
                    retry_after = response.headers.get("retry-after")
                    wait = self.retry.wait_after_503_s(parse_retry_after_s(retry_after))
                if wait is None:
                    try:
                        yield response
                    except httpx.TimeoutException as error:
                        raise _timeout(method, path, self.http.base_url, error) from error
                    return
            finally:
                response.close()
            self._before_retry(method, path, attempt, wait, f"503 Retry-After: {retry_after}")

    def _before_retry(self, method: str, path: str, attempt: int, wait_s: float, why: str) -> None:
        event = RetryEvent(method, path, attempt, wait_s, why)
        log.info("%s %s attempt %d: %s; retrying in %.3g s", method, path, attempt, why, wait_s)
        if self.on_retry is not None:
            self.on_retry(event)
        self._sleep(wait_s)

    @staticmethod
    def _error(method: str, path: str, response: httpx.Response) -> SmmHTTPError:
        try:
            body: object = response.json()
        except ValueError:
            body = response.text
        return SmmHTTPError.from_body(
            method,
            path,
            response.status_code,
            body,
            parse_retry_after_s(response.headers.get("retry-after")),
            response.headers.get(REQUEST_ID_HEADER),
        )

    # -- lifetime ----------------------------------------------------------------------

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> SmmClient:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.close()


def _timeout(
    method: str, path: str, base_url: httpx.URL, error: httpx.TimeoutException
) -> SmmTimeoutError:
    return SmmTimeoutError(
        f"{method} {path}: no answer from {base_url} within the timeout "
        f"({type(error).__name__}); not retried, the server may still be computing it"
    )
