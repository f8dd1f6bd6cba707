"""Row-parallel compiled calls: a kernel's rows split into one chunk per thread.

After sampling, a request's stages run on one core while the others idle (only the flow
network uses them, through onnxruntime's threads). The compiled kernels release the GIL
and each row's result depends on that row alone, so the rows of one call can run on
several threads at once and give the same numbers. A chunk is worth a thread only when it
is long enough to repay the hand-off (tens of microseconds): below `MIN_CHUNK_ROWS` rows a
call stays on the caller's thread.

The two kernels a request splits most (the Newton steps and the self-clearance at joint
values) hand their first chunk over in C instead (`helper_rows`, row_helper.h): one
persistent helper thread that spins for a few milliseconds after each part, so a request's
split calls find it running. Through Python (this module's thread pool and the GIL) a
hand-off to a thread idle for a millisecond took 100-200 us on a 2-core VM, the idle
core's wake-up and the GIL's hand-offs, against about 11 us hot; between two C threads,
under 1 us.

A call splits only while its query is the only one the process is answering
(`ANSWERING`, counted by `run.answer`): two requests computing at once, or a batch's
worker threads, already take the cores, and a split call's helper would have to take a
core from the other query while its caller waited for it. Measured on a 2-core Intel
Xeon: 4 clients of `python -m tools.load` (two computations at once) got 33.6-34.1
answers a second with every call splitting and 41.6-41.7 with this rule (p99 331-369 ->
266-267 ms), and 64 iiwa14 pose targets in one batch on two workers took 1540-1570 ms
against 1190-1330.

A call whose result is needed only later, and which does not feed what comes before
that, runs beside the caller instead (`Aside`): the trace's least sigma_min and the
closest approach of two strands only flag the structure, so they overlap the rest of the
trace and the cutting into free pieces.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from functools import cache
from itertools import pairwise
from threading import Lock
from typing import Generic, TypeVar

T = TypeVar("T")

# Rows a chunk must have to get a thread of its own: 10 DLS steps of 128 iiwa14 pose rows
# take about 0.4 ms, a thread's hand-off tens of microseconds.
MIN_CHUNK_ROWS = 128


@cache
def _pool(threads: int) -> ThreadPoolExecutor:
    """The process's helper threads for `threads`-way calls (the caller is the last one)."""
    return ThreadPoolExecutor(max_workers=threads - 1, thread_name_prefix="smm-rows")


class InFlight:
    """How many of something (queries being answered, flow calls) run at this moment in
    the process, each counted in by `entered()` while its block runs."""

    def __init__(self) -> None:
        self._lock = Lock()
        self._count = 0

    @property
    def count(self) -> int:
        return self._count

    @contextmanager
    def entered(self) -> Iterator[int]:
        """Counts the caller in while the block runs; yields how many others ran."""
        with self._lock:
            others = self._count
            self._count += 1
        try:
            yield others
        finally:
            with self._lock:
                self._count -= 1

    @property
    def alone(self) -> bool:
        """At most one runs: the caller's own."""
        return self._count <= 1

    def threads(self, threads: int) -> int:
        """`threads` while the caller's runs alone, else 1."""
        return threads if self.alone else 1


# The queries being answered (`run.answer` counts each in): while two or more are, their
# threads already take the cores, and a call that split its rows would hand half to a
# helper thread with no core free for it while the caller waited.
ANSWERING = InFlight()


def chunks(rows: int, threads: int, min_rows: int = MIN_CHUNK_ROWS) -> list[slice]:
    """`rows` split into at most `threads` consecutive slices of nearly equal length, none
    shorter than `min_rows` (one slice, all rows, when they are too few to split)."""
    count = max(1, min(threads, rows // max(min_rows, 1)))
    bounds = [rows * k // count for k in range(count + 1)]
    return [slice(a, b) for a, b in pairwise(bounds)]


def helper_rows(rows: int, threads: int, min_rows: int = MIN_CHUNK_ROWS) -> int:
    """How many of a compiled call's first rows go to its row helper (row_helper.h): the
    first of `chunks(rows, 2)` when `threads` > 1 and the rows split, else 0 (every row on
    the caller's thread)."""
    parts = chunks(rows, min(ANSWERING.threads(threads), 2), min_rows)
    return parts[0].stop if len(parts) > 1 else 0


def over_rows(
    call: Callable[[slice], T], rows: int, threads: int, min_rows: int = MIN_CHUNK_ROWS
) -> list[T]:
    """`call` on each of `chunks(rows, threads, min_rows)`, the first ones on helper threads
    and the last on the caller's, in order of the slices. `call` must release the GIL for
    its work and write only its own rows. A kernel whose rows each cost far more than a
    DLS step (a whole walk on the fibre) passes a smaller `min_rows`."""
    parts = chunks(rows, ANSWERING.threads(threads), min_rows)
    if len(parts) == 1:
        return [call(parts[0])]
    helpers = [_pool(threads).submit(call, part) for part in parts[:-1]]
    last = call(parts[-1])
    return [future.result() for future in helpers] + [last]


# Rows a call set aside must have to run beside the caller: the trace's sigma_min over
# the 111 reached points of a planar 3R target (median) took longer set aside than in
# line, the 610 of an iiwa14 pose target less.
MIN_ASIDE_ROWS = 256


@cache
def _aside_pool() -> ThreadPoolExecutor:
    """The process's thread for work set aside while the caller goes on."""
    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="smm-aside")


class Aside(Generic[T]):
    """`call()` on a thread of its own while the caller goes on (`threads` > 1 and `rows`
    at least `min_rows`), or at once on the caller's; `result()` waits for it. `call` must
    release the GIL for its work (a compiled kernel) to overlap anything; on fewer rows
    than `min_rows` it is too short to repay the hand-off and the wake-up."""

    def __init__(
        self, call: Callable[[], T], threads: int, rows: int, min_rows: int = MIN_ASIDE_ROWS
    ) -> None:
        if ANSWERING.threads(threads) > 1 and rows >= min_rows:
            self._future = _aside_pool().submit(call)
        else:
            self._future = Future()
            self._future.set_result(call())

    def result(self) -> T:
        return self._future.result()
