"""Many queries of one model (a planner's targets along a path), each answered as `run` answers it.

Every query goes through the pieces of `run.py` (target -> sample -> correct -> accept ->
connect -> components) with its own seed, so its answer is the one `run` gives it, to
the bit. With `sampling_threads` above 0 the flow network (stage 2) samples the next
queries in worker threads while the calling thread corrects, connects and summarises
the earlier ones in order: onnxruntime releases the GIL while it evaluates the network,
so with a core to spare the two overlap (two threads evaluating the network at once did
twice the work of one, measured on an idle 2-core machine). The service's default is 0:
measured end to end with another job on one of the two cores, sampling ahead gained
nothing, and a computation slot is meant to hold one core.

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
returned in order, and the first one it stopped names its stage.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

from service.errors import DeadlineExceededError
from service.pipeline.arrays import FloatArray
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.run import Stopwatch, answer, answer_samples, encode, in_rounds, sample
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


def _sample_timed(
    model: SmmModel, query: Query, target: Target, watch: Stopwatch, deadline: Deadline
) -> FloatArray:  # (N, n) rad
    with watch.stage("sample"):
        return sample(model, query, target, deadline)


def run_batch(
    model: SmmModel,
    queries: Sequence[Query],
    deadline: Deadline = NO_DEADLINE,
    sampling_threads: int = 0,
) -> BatchResult:
    """Answer every query in order; `results[i]` equals `run(model, queries[i])` but for
    its timings, whose total is the sum of its stages (they do not run back to back).

    `sampling_threads`: worker threads that sample ahead (0: every stage in the calling
    thread, one query after another). Past `deadline`, the batch stops and returns the
    queries answered so far with the DeadlineExceededError that stopped it.
    """
    start_s = time.perf_counter()
    watches = [Stopwatch(total="stages") for _ in queries]
    targets = []
    for query, watch in zip(queries, watches, strict=True):
        with watch.stage("encode"):
            targets.append(encode(model, query))
    results: list[SmmResult] = []
    pool = ThreadPoolExecutor(sampling_threads) if sampling_threads > 0 else None
    futures: list[Future[FloatArray]] = []
    try:
        if pool is not None:  # a query drawn in rounds samples as it goes
            futures = [
                pool.submit(_sample_timed, model, query, target, watch, deadline)
                for query, target, watch in zip(queries, targets, watches, strict=True)
                if not in_rounds(model, query)
            ]
        ahead = iter(futures)
        for query, target, watch in zip(queries, targets, watches, strict=True):
            if pool is None or in_rounds(model, query):
                results.append(answer(model, query, target, watch, deadline))
            else:
                q_sampled_rad = next(ahead).result()
                results.append(answer_samples(model, query, target, q_sampled_rad, watch, deadline))
    except DeadlineExceededError as error:
        return BatchResult(results, error, (time.perf_counter() - start_s) * 1e3)
    finally:
        if pool is not None:
            # Samples not started are dropped; one under way stops at its next deadline
            # check (the deadline has passed) or finishes its query.
            pool.shutdown(wait=True, cancel_futures=True)
    return BatchResult(results, None, (time.perf_counter() - start_s) * 1e3)
