"""Admission control for the pipeline: a bounded number of computations, a bounded wait.

At most `max_in_flight` computations run at once; at most `max_queued` requests wait
for a slot, each for at most `max_wait_s` (or what is left of its deadline). A request
that finds the wait full, or waits too long, gets OverloadedError (503 with
Retry-After) instead of queueing without limit, so a burst costs clients a prompt
refusal and costs the process nothing that grows.
"""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from service.errors import OverloadedError


class Admission:
    def __init__(
        self, max_in_flight: int, max_queued: int, max_wait_s: float, retry_after_s: int
    ) -> None:
        self.max_in_flight = max_in_flight
        self.max_queued = max_queued
        self.max_wait_s = max_wait_s
        self.retry_after_s = retry_after_s
        self.in_flight = 0  # computations holding a slot
        self.waiting = 0  # requests waiting for one
        self._slots = asyncio.Semaphore(max_in_flight)

    def _overloaded(self, why: str, reason: str) -> OverloadedError:
        return OverloadedError(
            f"server at capacity: {why} (SMM_MAX_IN_FLIGHT={self.max_in_flight}, "
            f"SMM_MAX_QUEUED={self.max_queued}, SMM_MAX_QUEUE_WAIT_S={self.max_wait_s:g}); "
            f"retry after {self.retry_after_s} s",
            self.retry_after_s,
            reason,
        )

    @asynccontextmanager
    async def slot(self, remaining_s: float) -> AsyncIterator[None]:
        """Hold a computation slot for the body of the `async with`.

        `remaining_s`: what is left of the request's deadline; the wait is the shorter of
        that and `max_wait_s`. Raises OverloadedError when no slot can be had in time.
        """
        if self._slots.locked():  # every slot taken (or others already waiting)
            if self.waiting >= self.max_queued:
                raise self._overloaded(
                    f"{self.in_flight} requests computing and {self.waiting} waiting",
                    "queue_full",
                )
            wait_s = max(0.0, min(self.max_wait_s, remaining_s))
            self.waiting += 1
            try:
                async with asyncio.timeout(wait_s):
                    await self._slots.acquire()
            except TimeoutError:
                raise self._overloaded(
                    f"no computation slot free within {wait_s:.3g} s", "queue_timeout"
                ) from None
            finally:
                self.waiting -= 1
        else:
            await self._slots.acquire()
        self.in_flight += 1
        try:
            yield
        finally:
            self.in_flight -= 1
            self._slots.release()
