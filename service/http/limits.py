"""Limits at the HTTP layer, before a route runs: open requests, body size, content type.

- At most `max_open_requests` requests are received or answered at once (the probes
  and /metrics excepted, so an operator still sees a saturated server); one more gets
  503 with Retry-After at once. With the body limit this bounds the memory that
  bodies can hold, whatever clients send.
- A route that takes a JSON body gets one of at most `max_body_bytes` (413 beyond,
  refused from Content-Length before reading when it is declared, else while reading)
  and with a JSON content type (415 otherwise).
"""

from __future__ import annotations

from collections.abc import Callable
from email.message import Message as MimeMessage

from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.http.asgi import send_json_error
from service.http.paths import OPEN_PATHS


def is_json_content_type(value: str) -> bool:
    """application/json or application/<anything>+json, parameters (charset) allowed."""
    message = MimeMessage()
    message["content-type"] = value
    subtype = message.get_content_subtype()
    return message.get_content_maintype() == "application" and (
        subtype == "json" or subtype.endswith("+json")
    )


class RequestLimitsMiddleware:
    def __init__(
        self,
        app: ASGIApp,
        json_routes: frozenset[tuple[str, str]],
        max_body_bytes: int,
        max_open_requests: int,
        retry_after_s: int,
        on_reject: Callable[[str], None],
    ) -> None:
        """`json_routes`: (method, path) pairs that read a JSON body; `on_reject(reason)`
        counts a capacity refusal."""
        self.app = app
        self.json_routes = json_routes
        self.max_body_bytes = max_body_bytes
        self.max_open_requests = max_open_requests
        self.retry_after_s = retry_after_s
        self.on_reject = on_reject
        self.open_requests = 0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["path"] in OPEN_PATHS:
            await self.app(scope, receive, send)
            return
        if self.open_requests >= self.max_open_requests:
            self.on_reject("open_requests")
            await send_json_error(
                send,
                503,
                f"server at capacity: {self.open_requests} requests open "
                f"(SMM_MAX_OPEN_REQUESTS={self.max_open_requests}); "
                f"retry after {self.retry_after_s} s",
                {"Retry-After": str(self.retry_after_s)},
            )
            return
        self.open_requests += 1
        try:
            if (scope["method"], scope["path"]) in self.json_routes:
                await self._json_body_route(scope, receive, send)
            else:
                await self.app(scope, receive, send)
        finally:
            self.open_requests -= 1

    async def _json_body_route(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = Headers(scope=scope)
        content_type = headers.get("content-type", "")
        if not is_json_content_type(content_type):
            got = repr(content_type[:100]) if content_type else "none"
            await send_json_error(
                send,
                415,
                f"content-type: must be application/json (or application/*+json), got {got}",
            )
            return
        declared = headers.get("content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > self.max_body_bytes):
            await self._too_large(send, declared)
            return
        body = bytearray()
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                return  # the client went away; nobody to answer
            body += message.get("body", b"")
            if len(body) > self.max_body_bytes:
                await self._too_large(send, f"more than {self.max_body_bytes}")
                return
            if not message.get("more_body", False):
                break
        await self.app(scope, _replay(bytes(body), receive), send)

    async def _too_large(self, send: Send, size: str) -> None:
        await send_json_error(
            send,
            413,
            f"body: at most {self.max_body_bytes} bytes (SMM_MAX_BODY_BYTES), got {size} bytes",
        )


def _replay(body: bytes, receive: Receive) -> Receive:
    """A receive channel that yields the already-read body once, then the client's own."""
    delivered = False

    async def replay() -> Message:
        nonlocal delivered
        if not delivered:
            delivered = True
            return {"type": "http.request", "body": body, "more_body": False}
        return await receive()

    return replay
