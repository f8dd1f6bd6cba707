"""What the client raises: every failure is an `SmmClientError`, and the server's own words
come through.

`SmmHTTPError` is an error answer (4xx/5xx) with the server's status, its `detail` text
and, for a 422, each field error's location and message. `SmmTimeoutError` and
`SmmConnectionError` are the transport's failures, after the retries the policy allows.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


class SmmClientError(Exception):
    """Base of every error the client raises."""


@dataclass(frozen=True)
class FieldError:
    """One entry of a 422's `detail`: where in the body, and what the server said."""

    loc: tuple[str | int, ...]  # ("body", "target", "position"), FastAPI's location
    msg: str  # names the field and what it allows
    type: str

    @property
    def field(self) -> str:
        """`("body", "targets", 1, "seed")` -> `targets[1].seed`; the bare body is `body`."""
        parts = self.loc[1:] if self.loc and self.loc[0] == "body" else self.loc
        path = ""
        for part in parts:
            path += f"[{part}]" if isinstance(part, int) else (f".{part}" if path else part)
        return path or "body"


class SmmHTTPError(SmmClientError):
    """The server answered with an error status.

    `status_code`: the HTTP status; `detail`: the server's message (for a 422, its field
    messages joined by "; "); `field_errors`: a 422's entries, empty otherwise;
    `retry_after_s`: a 503's Retry-After, if any; `request_id`: the server's X-Request-ID
    (quote it when reading the server's log).
    """

    def __init__(
        self,
        method: str,
        path: str,
        status_code: int,
        detail: str,
        field_errors: list[FieldError],
        retry_after_s: float | None,
        request_id: str | None,
    ) -> None:
        self.method = method
        self.path = path
        self.status_code = status_code
        self.detail = detail
        self.field_errors = field_errors
        self.retry_after_s = retry_after_s
        self.request_id = request_id
        where = f" (request id {request_id})" if request_id else ""
        super().__init__(f"{method} {path} -> {status_code}: {detail}{where}")

    @classmethod
    def from_body(
        cls,
        method: str,
        path: str,
        status_code: int,
        body: Any,
        retry_after_s: float | None,
        request_id: str | None,
    ) -> SmmHTTPError:
        """From the decoded JSON body: `{"detail": str}` or `{"detail": [field errors]}`;
        anything else (a proxy's HTML page, say) is quoted as it came."""
        detail = body.get("detail") if isinstance(body, dict) else None
        field_errors: list[FieldError] = []
        if isinstance(detail, list):
            for entry in detail:
                if isinstance(entry, dict):
                    loc = entry.get("loc", [])
                    field_errors.append(
                        FieldError(
                            loc=tuple(p for p in loc if isinstance(p, str | int)),
                            msg=str(entry.get("msg", "")),
                            type=str(entry.get("type", "")),
                        )
                    )
            text = "; ".join(error.msg for error in field_errors) or str(detail)
        elif isinstance(detail, str):
            text = detail
        else:
            text = str(body)[:500]
        return cls(method, path, status_code, text, field_errors, retry_after_s, request_id)


class SmmTransportError(SmmClientError):
    """No answer came back: the connection failed or the request timed out."""


class SmmConnectionError(SmmTransportError):
    """The server could not be reached, or dropped the connection, on every attempt."""


class SmmTimeoutError(SmmTransportError):
    """No answer within the client's timeout. Not retried: the server may still be
    computing it, and sending it again would only add to its load."""
