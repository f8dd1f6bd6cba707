"""The outermost middleware: a request id, an access log line and request metrics.

Every response carries `X-Request-ID`: the client's own when it sent a sane one
(1-128 of letters, digits and `._:-`), else a fresh one; every log line the request
causes carries the same id. An exception that escapes the app becomes a 500 JSON body
naming that id (its traceback goes to the log, not to the client), and the process
goes on serving.
"""

from __future__ import annotations

import logging
import re
import time
import uuid
from typing import Any

from starlette.datastructures import Headers, MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.http.asgi import send_json_error
from service.observability.logs import REQUEST_ID, log_event
from service.observability.metrics import Metrics

REQUEST_ID_HEADER = "X-Request-ID"
_SANE_ID = re.compile(r"[A-Za-z0-9._:-]{1,128}")
UNMATCHED_ROUTE = "unmatched"


def request_id_of(headers: Headers) -> str:
    """The client's request id when it is sane, else a fresh random one."""
    offered = headers.get(REQUEST_ID_HEADER, "")
    return offered if _SANE_ID.fullmatch(offered) else uuid.uuid4().hex


def route_template(scope: Scope, known_paths: frozenset[str]) -> str:
    """The matched route's path template, else the path when it is a known one (a request
    refused before routing), else "unmatched": a bounded set of labels."""
    route: Any = scope.get("route")
    path = getattr(route, "path", None)
    if isinstance(path, str):
        return path
    return scope["path"] if scope["path"] in known_paths else UNMATCHED_ROUTE


class RequestContextMiddleware:
    def __init__(
        self, app: ASGIApp, metrics: Metrics, logger: logging.Logger, known_paths: frozenset[str]
    ) -> None:
        self.app = app
        self.metrics = metrics
        self.logger = logger
        self.known_paths = known_paths

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        request_id = request_id_of(Headers(scope=scope))
        token = REQUEST_ID.set(request_id)
        start = time.perf_counter()
        status = 500
        started = False

        async def send_with_id(message: Message) -> None:
            nonlocal status, started
            if message["type"] == "http.response.start":
                started = True
                status = message["status"]
                MutableHeaders(scope=message).append(REQUEST_ID_HEADER, request_id)
            await send(message)

        self.metrics.requests_in_flight.inc()
        try:
            await self.app(scope, receive, send_with_id)
        except Exception:
            status = 500
            self.logger.exception(
                "unhandled error", extra={"fields": {"path": scope.get("path", "")[:200]}}
            )
            if not started:
                detail = f"internal error; the server logged it under request id {request_id}"
                await send_json_error(send_with_id, 500, detail)
        finally:
            self.metrics.requests_in_flight.dec()
            duration_s = time.perf_counter() - start
            route = route_template(scope, self.known_paths)
            model = str(scope.get("state", {}).get("model", ""))
            self.metrics.observe_request(route, scope["method"], model, status, duration_s)
            log_event(
                self.logger,
                logging.INFO,
                "request",
                method=scope["method"],
                path=scope.get("path", "")[:200],
                route=route,
                status=status,
                duration_ms=round(duration_s * 1e3, 2),
                model=model,
                client=(scope.get("client") or ("", 0))[0],
            )
            REQUEST_ID.reset(token)
