"""A batch's targets on threads against the same targets on processes: what the GIL costs.

    python -m tools.batch_processes --model iiwa14-pose --targets 64 [--json PATH]

In process, no HTTP, the batch benchmark's targets (`tools.batch_benchmark`: the FK of
configurations uniform in the joint limits, seed 7, target i with seed i) at the model's
served default N, answered three ways, round after round interleaved:

- one after another: `run_batch` (service/pipeline/batch.py) on one thread, each target
  answered as a single request is (its compiled calls' rows split over the cores);
- the service's batch: `run_batch` on the threads a `POST /smm/batch` gets
  (`Settings.batch_threads_per_request`), the model opened as the service opens it;
- processes: as many forks of this process, each answering every P-th target with
  `run_batch` on one thread. They are forked before this process opens any model (no
  thread of onnxruntime's or of the compiled kernels crosses a fork), and each opens the
  model itself; a round starts when all of them are at a barrier and ends when the last
  is done.

The figure is ms per target, the median over the rounds. Threads share one interpreter,
so a batch's Python runs one target at a time (the GIL): a thread back from a compiled
call waits while the other's Python runs, where processes each run their own. What the
processes save over the threads is what the GIL costs the service's batch. Every
process's answers are checked equal to the threads' (their JSON, timings aside, by
digest): the figures are reported beside that check.
"""

from __future__ import annotations

import argparse
import hashlib
import multiprocessing
import statistics
import sys
import time
from multiprocessing.synchronize import Barrier
from typing import Any

from service.api.answers import encode
from service.api.smm import query_for_model, smm_fields
from service.config import Settings
from service.manifest import REPO_MODELS_DIR, bundled_model_ids
from service.models.registry import ServedModel, load_model
from service.pipeline.batch import run_batch
from service.pipeline.types import Query, SmmResult
from service.wire import SmmRequest
from tools.batch_benchmark import TARGETS_SEED, target_of
from tools.batch_bounds import processes_sentence
from tools.records import command_line, write_record
from training.checkout import git_commit
from training.evaluate.targets import uniform_configurations
from training.machine import Machine

ROUNDS = 3


def batch_queries(model: ServedModel, count: int) -> list[Query]:
    """The batch benchmark's `count` targets as the model's queries: target i with seed i,
    at the served default N."""
    manifest = model.manifest
    q_targets = uniform_configurations(model.limits, count, TARGETS_SEED)
    common = {"robot": manifest.robot, "task": manifest.task.name}
    requests = [
        SmmRequest.model_validate({**common, "target": target_of(model, q), "seed": i})
        for i, q in enumerate(q_targets)
    ]
    return [query_for_model(request, model) for request in requests]


def answer_digest(model: ServedModel, query: Query, result: SmmResult) -> str:
    """sha256 of the answer's JSON as POST /smm sends it, its timings left out."""
    fields = smm_fields(model, query, result)
    fields["timings_ms"] = {}
    return hashlib.sha256(encode(fields)).hexdigest()


def _open(model_id: str, threads: int) -> ServedModel:
    settings = Settings()
    return load_model(REPO_MODELS_DIR / model_id, threads, settings.compiled_int8)


def _answer_share(
    model_id: str,
    count: int,
    share: int,
    processes: int,
    rounds: int,
    barrier: Barrier,
    done: Any,  # multiprocessing.Queue: (share,) once a round's answers are in
    digests: Any,  # multiprocessing.Queue: (share, [digest of each answered target])
) -> None:
    """In a forked process: open the model on one thread and answer targets share,
    share + processes, ... with `run_batch` on one thread, once per round."""
    model = _open(model_id, threads=1)
    queries = batch_queries(model, count)[share::processes]
    run_batch(model, queries[:1])  # warm
    for round_index in range(rounds):
        barrier.wait()
        batch = run_batch(model, queries)
        done.put(share)
        if round_index == 0:
            answered = zip(queries, batch.results, strict=True)
            digests.put((share, [answer_digest(model, q, r) for q, r in answered]))


def measure(model_id: str, count: int, processes: int, rounds: int = ROUNDS) -> dict[str, Any]:
    """ms per target of `count` targets one after another, on the service's batch threads and
    on `processes` forked processes, median over `rounds` interleaved rounds, and whether
    every process's answer equals the threads' (`mismatched`: the targets whose did not)."""
    context = multiprocessing.get_context("fork")
    barrier = context.Barrier(processes + 1)
    done, digests = context.Queue(), context.Queue()
    workers = [
        context.Process(
            target=_answer_share,
            args=(model_id, count, share, processes, rounds, barrier, done, digests),
            daemon=True,
        )
        for share in range(processes)
    ]
    for worker in workers:  # before this process opens any model
        worker.start()
    settings = Settings()
    threads = settings.batch_threads_per_request
    model = _open(model_id, settings.onnx_threads_per_session)
    queries = batch_queries(model, count)
    run_batch(model, queries[:threads], threads=threads)  # warm
    times: dict[str, list[float]] = {"one_after_another": [], "threads": [], "processes": []}
    expected: list[str] = []
    for round_index in range(rounds):
        start = time.perf_counter()
        run_batch(model, queries)
        times["one_after_another"].append(time.perf_counter() - start)
        start = time.perf_counter()
        batch = run_batch(model, queries, threads=threads)
        times["threads"].append(time.perf_counter() - start)
        if round_index == 0:
            answered = zip(queries, batch.results, strict=True)
            expected = [answer_digest(model, q, r) for q, r in answered]
        barrier.wait()
        start = time.perf_counter()
        for _ in workers:
            done.get(timeout=600)
        times["processes"].append(time.perf_counter() - start)
    got = [""] * count
    for _ in workers:
        share, answers = digests.get(timeout=600)
        got[share::processes] = answers
    for worker in workers:
        worker.join(timeout=60)
    ms = {name: statistics.median(t) * 1e3 / count for name, t in times.items()}
    return {
        "model": f"{model.manifest.model_id}@{model.version}",
        "targets": count,
        "num_samples": model.manifest.defaults.num_samples,
        "rounds": rounds,
        "threads": threads,
        "processes": processes,
        "one_after_another_ms_per_target": ms["one_after_another"],
        "threads_ms_per_target": ms["threads"],
        "processes_ms_per_target": ms["processes"],
        "mismatched": [i for i, (a, b) in enumerate(zip(expected, got, strict=True)) if a != b],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    parser.add_argument("--model", default="iiwa14-pose", choices=bundled_model_ids())
    parser.add_argument("--targets", type=int, default=64)
    parser.add_argument(
        "--processes", type=int, default=0, help="forked processes (0: the batch's threads)"
    )
    parser.add_argument("--rounds", type=int, default=ROUNDS)
    parser.add_argument("--json", help="write the record here")
    args = parser.parse_args(argv)
    if args.targets < 1 or args.rounds < 1 or args.processes < 0:
        parser.error("--targets and --rounds must be at least 1, --processes at least 0")
    machine = Machine.now()
    processes = args.processes or Settings().batch_threads_per_request
    record = measure(args.model, args.targets, processes, args.rounds)
    print(processes_sentence(record))
    if args.json:
        full = {
            "command": command_line("tools.batch_processes", argv),
            "git_commit": git_commit(),
            "machine": machine.ended().as_json(),
            **record,
        }
        write_record(args.json, full)
    return 0 if not record["mismatched"] else 1


if __name__ == "__main__":
    sys.exit(main())
