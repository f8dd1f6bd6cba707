"""When the client sends a request again, and how long it waits first.

Every call the client makes is idempotent: the GETs, and POST /smm and /smm/batch too,
because an answer is a function of the body (the same seed gives the same answer, and
the client always sends one; its default is 0). So sending a request again is safe, and
the policy retries, within `max_attempts` attempts in all:

- a 503 that carries `Retry-After` (the server at capacity): after waiting exactly what
  it asks, unless that exceeds `max_retry_after_s`, when the 503 is raised at once;
- a connection that could not be made, or was dropped before an answer came (a server
  restarting or draining): after `backoff_s`, doubling each time up to `max_backoff_s`.

Never retried: a 503 without `Retry-After` (a model that failed verification stays
failed), every other error status (the same body gets the same error), and a timeout
while waiting for the answer (the server may still be computing it; another copy would
only add to its load).
"""

from __future__ import annotations

import email.utils
import time
from dataclasses import dataclass

import httpx

# Transport failures after which the request is sent again: no connection was made, or
# it broke before an answer came.
RETRIED_TRANSPORT_ERRORS: tuple[type[httpx.TransportError], ...] = (
    httpx.ConnectError,
    httpx.ConnectTimeout,
    httpx.ReadError,
    httpx.WriteError,
    httpx.RemoteProtocolError,
)


@dataclass(frozen=True)
class RetryPolicy:
    max_attempts: int = 4  # attempts in all, the first included; 1 turns retries off
    max_retry_after_s: float = 30.0  # a longer Retry-After is not waited for
    backoff_s: float = 0.5  # first wait after a connection error
    max_backoff_s: float = 8.0

    def __post_init__(self) -> None:
        if self.max_attempts < 1:
            raise ValueError(f"max_attempts must be at least 1, got {self.max_attempts}")

    def wait_after_503_s(self, retry_after_s: float | None) -> float | None:
        """Seconds to wait before sending again after a 503, or None: do not retry."""
        if retry_after_s is None or retry_after_s > self.max_retry_after_s:
            return None
        return retry_after_s

    def wait_after_transport_error_s(self, attempt: int) -> float:
        """Seconds to wait after attempt number `attempt` (1-based) failed to connect."""
        return min(self.backoff_s * 2.0 ** (attempt - 1), self.max_backoff_s)


@dataclass(frozen=True)
class RetryEvent:
    """One retry, as the client's `on_retry` callback sees it (before the wait)."""

    method: str
    path: str
    attempt: int  # the attempt that failed, 1-based
    wait_s: float  # how long the client waits before the next attempt
    reason: str  # "503 Retry-After: 1" or the transport error's name


def parse_retry_after_s(value: str | None, now_s: float | None = None) -> float | None:
    """A Retry-After header in seconds: delta-seconds or an HTTP date; None if absent or
    unreadable."""
    if value is None:
        return None
    value = value.strip()
    if value.isdigit():
        return float(value)
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError):
        return None
    now = time.time() if now_s is None else now_s
    return max(0.0, when.timestamp() - now)
