"""Many queries of one model (a planner's targets along a path), each answered as `run` answers it.

Every query goes through the pieces of `run.py` (target -> sample -> correct -> accept ->
connect -> components) with its own seed, so its answer is the one `run` gives it, to
the bit, whichever thread answers it. With `threads` above 1, that many worker threads
answer the queries at once, each query whole: the flow network and the compiled kernels
(native.c) release the GIL, and the rest of each stage's Python holds it, which bounds
the gain (docs/speed.md, the batch with one thread and with the default's). The answers
are collected in order.

Why the targets' samples are not concatenated into one network call per Euler step:
measured with one onnxruntime thread (2-core AMD EPYC), a call costs the same per row
from 50 to 2,000 rows (float32: planar 3R 4.5 us, iiwa14 pose 21 us; int8 iiwa14 pose
6.9 us from 100 to 1,000) and more above (float32 6.0 and 27 us at 64,000 rows, int8
9.8 us at 16,000: out of cache), so one call over every target saves nothing. And it
would change the answers: an int8 flow quantises its activations with one scale per call
(concatenating a second target's 500 draws moved the first's velocities by up to 15), and
`euler_integrate`'s envelope is set by the largest draw of all the rows it is given. So
per query the network sees exactly the rows a single request gives it. Correction is
per query too: `correct` takes one target, and the kinematics already costs the same per
row from 1,000 rows up (`service/models/chain.py`).

The deadline is shared by the whole batch: the queries answered before it passed are
returned in order, and the first one it stopped names its stage. `on_answer` hears of each
answer, in order, as soon as it and those before it are done, so a caller can send it on
while the workers answer the next queries (POST /smm/batch's NDJSON stream).
`on_computed` hears of every answer computed, in the thread that computed it, whether or
not the batch returns it: one a worker finished after the batch stopped (the client left,
or an earlier query ran past the deadline) is work done all the same, which the server's
metrics count.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

from service.errors import DeadlineExceededError
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.run import Stopwatch, answer, encode
from service.pipeline.targets import Target
from service.pipeline.types import Query, SmmModel, SmmResult


@dataclass(frozen=True)
class BatchResult:
    """The answers of a batch's queries, in order, as many as were answered in time."""

    results: list[SmmResult]  # results[i] answers queries[i]; a prefix of the queries
    deadline_error: DeadlineExceededError | None  # what stopped the batch, None when complete
    total_ms: float  # wall time of the whole batch

    @property
    def complete(self) -> bool:
        return self.deadline_error is None


def run_batch(
    model: SmmModel,
    queries: Sequence[Query],
    deadline: Deadline = NO_DEADLINE,
    threads: int = 1,
    on_answer: Callable[[int, SmmResult], None] | None = None,
    on_computed: Callable[[SmmResult], None] | None = None,
) -> BatchResult:
    """Answer every query; `results[i]` equals `run(model, queries[i])` but for its
    timings, whose total is the sum of its stages (they do not run back to back).

    `threads`: worker threads answering queries at once (1: one after another in the
    calling thread). Past `deadline`, the batch stops and returns the queries answered so
    far, in order, with the DeadlineExceededError that stopped the first one unanswered.
    `on_answer(i, results[i])` is called in the calling thread, in order, as each answer
    is ready; an exception it raises stops the batch (the queries under way finish, the
    rest are not started) and propagates. `on_computed(result)` is called for every query
    answered, in the thread that answered it, as soon as it is; it must not raise.
    """
    start_s = time.perf_counter()
    watches = [Stopwatch(total="stages") for _ in queries]
    targets = []
    for query, watch in zip(queries, watches, strict=True):
        with watch.stage("encode"):
            targets.append(encode(model, query))
    jobs = list(zip(queries, targets, watches, strict=True))

    def answered(query: Query, target: Target, watch: Stopwatch) -> SmmResult:
        result = answer(model, query, target, watch, deadline)
        if on_computed is not None:
            on_computed(result)
        return result

    results: list[SmmResult] = []
    pool = ThreadPoolExecutor(threads, thread_name_prefix="smm-batch") if threads > 1 else None
    try:
        if pool is None:  # one after another, in the calling thread
            answers = (answered(q, target, watch) for q, target, watch in jobs)
        else:
            futures: list[Future[SmmResult]] = [
                pool.submit(answered, query, target, watch) for query, target, watch in jobs
            ]
            answers = (future.result() for future in futures)
        for result in answers:  # in order
            results.append(result)
            if on_answer is not None:
                on_answer(len(results) - 1, result)
    except DeadlineExceededError as error:
        return BatchResult(results, error, (time.perf_counter() - start_s) * 1e3)
    finally:
        if pool is not None:
            # Queries not started are dropped; one under way stops at its next deadline
            # check (the deadline has passed) or finishes.
            pool.shutdown(wait=True, cancel_futures=True)
    return BatchResult(results, None, (time.perf_counter() - start_s) * 1e3)
