"""Optional API key: when `SMM_API_KEY` is set, every route but the probes and /metrics needs it.

The key goes in an `X-API-Key` header (or `Authorization: Bearer <key>`); anything else
gets 401 before the request reaches a route, unknown paths included, so an
unauthenticated client learns nothing about the service. Keys are compared in
constant time.
"""

from __future__ import annotations

import hmac

from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

from service.http.asgi import send_json_error
from service.http.paths import OPEN_PATHS

API_KEY_HEADER = "X-API-Key"
UNAUTHORIZED_MESSAGE = (
    f"missing or wrong API key: send it in the {API_KEY_HEADER} header "
    "(or Authorization: Bearer <key>); only /healthz, /readyz and /metrics are open"
)


def presented_key(headers: Headers) -> str | None:
    """The key a request presents, from X-API-Key or a Bearer Authorization header."""
    key = headers.get(API_KEY_HEADER)
    if key is not None:
        return key
    scheme, _, credentials = headers.get("authorization", "").partition(" ")
    return credentials.strip() if scheme.lower() == "bearer" else None


class ApiKeyMiddleware:
    def __init__(self, app: ASGIApp, api_key: str) -> None:
        self.app = app
        self._key = api_key.encode()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["path"] in OPEN_PATHS:
            await self.app(scope, receive, send)
            return
        key = presented_key(Headers(scope=scope))
        if key is not None and hmac.compare_digest(key.encode(), self._key):
            await self.app(scope, receive, send)
            return
        challenge = {"WWW-Authenticate": f'ApiKey header="{API_KEY_HEADER}"'}
        await send_json_error(send, 401, UNAUTHORIZED_MESSAGE, challenge)
