"""POST /smm/batch's answer as NDJSON lines, each sent as soon as its target is answered.

A batch of 64 iiwa14 pose targets at N = 1000 is about 23 MB of JSON. As one object, the
client can read none of it before the last target is answered and encoded, and then reads
it all at once, while the server's cores stand idle. As lines (`Accept:
application/x-ndjson`), a client parses each answer while the server computes the next,
and the server holds no more than the lines not yet sent.

The lines are SmmBatchResponse cut at its results (service/wire.py): the SmmBatchHead,
one BatchItemOut per target in order, the SmmBatchEnd; joined back (`of_lines`) they are
the JSON answer, value for value. The statuses are those of the JSON answer, decided
before the first line is sent: a 503 when no slot is free, a 504 when the deadline passes
before the first target is answered. Once the lines have begun, a deadline marks the rest
deadline_exceeded, as in the JSON answer; a stream that stops without its SmmBatchEnd was
cut off (a server fault after the 200 was sent, logged there).

The batch runs in a worker thread (`smm_batch.answer_lines`, holding its computation
slot as the JSON answer's does) and hands each encoded line to the event loop through a
`BatchLines`. A client that goes away stops it: the targets under way finish, the rest
are not started, and the slot is freed.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import AsyncGenerator

from fastapi import Request

from service.wire import NDJSON

_END = b""  # after the last line


def wants_lines(request: Request) -> bool:
    """Whether the client asked for the NDJSON lines (its Accept header names them)."""
    return NDJSON in request.headers.get("accept", "")


class ClientGone(Exception):
    """The client stopped reading the lines: stop computing them."""


class BatchLines:
    """The lines of one batch, put by the worker thread and read on the event loop."""

    def __init__(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._lines: asyncio.Queue[bytes] = asyncio.Queue()
        self.first = self._loop.create_future()  # set once the first target is answered
        self.stop = threading.Event()  # set when the client goes away

    def put(self, line: bytes) -> None:
        """From the worker thread: queue a line (ClientGone once nobody reads them)."""
        if self.stop.is_set():
            raise ClientGone
        self._loop.call_soon_threadsafe(self._put, line)

    def close(self) -> None:
        """From the worker thread: there are no more lines."""
        self._loop.call_soon_threadsafe(self._put, _END)

    def _put(self, line: bytes) -> None:
        if line != _END and not self.first.done():
            self.first.set_result(None)
        self._lines.put_nowait(line)

    async def read(self, computation: asyncio.Future[None]) -> AsyncGenerator[bytes, None]:
        """Every line, in order, until the last; then the computation's outcome (an error
        after the 200 was sent cuts the stream off). Leaving early stops the batch."""
        try:
            while (line := await self._lines.get()) != _END:
                yield line
            await computation
        finally:
            self.stop.set()


async def first_line_or_error(lines: BatchLines, computation: asyncio.Future[None]) -> None:
    """Wait until the first target is answered, or raise what ended the computation before
    it (OverloadedError: 503; DeadlineExceededError: 504)."""
    await asyncio.wait({lines.first, computation}, return_when=asyncio.FIRST_COMPLETED)
    if not lines.first.done():
        computation.result()  # raises what ended it
        raise AssertionError("a batch of at least one target answers it or raises")
