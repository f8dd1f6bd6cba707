"""Batch against singles: K targets as one POST /smm/batch against K POST /smm one after another.

    python -m tools.batch_benchmark --model iiwa14-pose --targets 64 [--num-samples N]

Over HTTP, as a planner would ask (`smm-serve` as a real uvicorn process on 127.0.0.1,
`tools.local_server.LocalServer`, asked through the project's client `service.client`,
like tools/benchmark.py's `OverHttp`): the targets are the FK of configurations uniform
in the joint limits (the evaluation's held-out targets, seed 7), target i with seed i,
at the model's served default N (the requests carry no num_samples, as a client asks
without options) unless --num-samples sets one. Each round sends the K single requests
one after another, then the one batch; the client's wall time of each, median over the
rounds, and their ratio (singles / batch: how many times faster the batch answers the
same targets). The client reads the batch as the server streams it (NDJSON, each
target's answer parsed while the server computes the next: `SmmClient.smm_batch`); each
round also asks for the batch as one JSON object, read and parsed once it has all
arrived, as a client without `Accept: application/x-ndjson` gets it. Every batch answer
must equal its single answer (JSON equal, timings aside): the figures are only reported
beside that check. Compare times only within one run.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from service.api.answers import encode
from service.api.smm import query_for_model, smm_fields
from service.client import RetryPolicy, SmmClient
from service.config import Settings
from service.manifest import REPO_MODELS_DIR, bundled_model_ids
from service.models.registry import ServedModel, load_model
from service.pipeline.run import run
from service.pipeline.targets import fields_reached
from service.wire import SmmBatchRequest, SmmBatchResponse, SmmRequest, SmmResponse
from tools.batch_bounds import (
    compiled_bound,
    compiled_sentence,
    cpu_bound,
    cpu_sentence,
    network_bound,
    network_sentence,
    same_work_bound,
    same_work_sentence,
)
from tools.connect_profile import KernelTimer
from tools.local_server import LocalServer
from tools.network_floor import avx2_network_products, every_core_peak
from training.evaluate.targets import uniform_configurations
from training.machine import Machine

ROUNDS = 3
TIMEOUT_S = 600.0
TARGETS_SEED = 7  # the evaluation's held-out targets


def target_of(model: ServedModel, q_rad: np.ndarray) -> dict[str, Any]:
    """The request's `target` reached by the configuration `q_rad` (n,): its FK."""
    manifest = model.manifest
    fk = model.kinematics(q_rad[None])
    return fields_reached(manifest.task, fk.position_m[0], fk.rotation[0]).wire()


def without_timings(answer: SmmResponse) -> SmmResponse:
    return answer.model_copy(update={"timings_ms": {}})


def mismatched_targets(batch: SmmBatchResponse, singles: Sequence[SmmResponse]) -> list[int]:
    """Indices whose batch answer differs from the single answer (timings aside)."""
    results = batch.results
    if len(results) != len(singles):
        return list(range(max(len(results), len(singles))))
    return [
        i
        for i, (result, answer) in enumerate(zip(results, singles, strict=True))
        if result.answer is None or without_timings(result.answer) != without_timings(answer)
    ]


def batch_against_singles(
    model: ServedModel,
    q_targets: np.ndarray,  # (K, n) configurations whose FK are the targets
    num_samples: int | None,
    rounds: int = ROUNDS,
    server: LocalServer | None = None,
    progress: Callable[[str], None] = lambda line: None,
    **server_settings: Any,
) -> dict[str, Any]:
    """Time K targets as one POST /smm/batch against K POST /smm one after another.

    `num_samples`: each target's, None for the model's served default (the requests then
    carry none, and the record names the default's N with `served_default`).
    `server`: a running LocalServer to ask (its limits must admit the batch); None starts
    one with the default settings but the batch limits and deadline raised to fit the K
    targets, and `server_settings` (Settings fields, `batch_threads=1`). Returns
    the medians over `rounds` of the client's wall time of the K singles and of the batch,
    their ratio, the server's own batch timings, and whether every batch answer equalled
    its single answer (`mismatched`: the indices that did not).
    """
    manifest = model.manifest
    targets = [target_of(model, q) for q in q_targets]
    served_default = num_samples is None
    common: dict[str, Any] = {"robot": manifest.robot, "task": manifest.task.name}
    if num_samples is None:
        num_samples = manifest.defaults.num_samples
    else:
        common["num_samples"] = num_samples
    singles = [
        SmmRequest.model_validate({**common, "target": t, "seed": i}) for i, t in enumerate(targets)
    ]
    batch_targets = [{"target": t, "seed": i} for i, t in enumerate(targets)]
    batch_body = {**common, "targets": batch_targets}
    batch = SmmBatchRequest.model_validate(batch_body)
    own = server is None
    if server is None:
        server = LocalServer(
            max_batch_targets=max(len(targets), 1),
            max_batch_samples=max(len(targets) * num_samples, 1),
            max_num_samples=max(num_samples, Settings().max_num_samples),
            request_deadline_s=TIMEOUT_S,
            max_body_bytes=max(65_536, 2 * len(json.dumps(batch_body))),
            **server_settings,
        ).start()
    singles_ms: list[float] = []
    batch_ms: list[float] = []
    batch_json_ms: list[float] = []
    mismatched: set[int] = set()
    server_timings: list[dict[str, float]] = []  # the batch's, by span
    singles_cpu: list[dict[str, float]] = []  # CPU ms of each round's singles, by process
    singles_server_ms: list[float] = []  # each round's singles' server totals, summed
    products = avx2_network_products(model, num_samples)
    peaks: list[float] = []  # the AVX2 product's peak on every core, after each round
    batch_cpu: list[dict[str, float]] = []
    try:
        no_retries = RetryPolicy(max_attempts=1)
        with SmmClient(server.url, timeout=TIMEOUT_S, retry=no_retries) as client:
            client.smm(singles[0])  # warm-up
            client.smm_batch(batch.model_copy(update={"targets": batch.targets[:2]}))
            for r in range(rounds):
                progress(f"{manifest.model_id}: round {r + 1} of {rounds}")
                start, cpu = time.perf_counter(), ProcessesCpu(server)
                single_answers = [client.smm(request) for request in singles]
                singles_ms.append((time.perf_counter() - start) * 1e3)
                singles_cpu.append(cpu.spent_ms())
                singles_server_ms.append(sum(a.timings_ms["total"] for a in single_answers))
                start, cpu = time.perf_counter(), ProcessesCpu(server)
                answer = client.smm_batch(batch)
                batch_ms.append((time.perf_counter() - start) * 1e3)
                batch_cpu.append(cpu.spent_ms())
                mismatched.update(mismatched_targets(answer, single_answers))
                start = time.perf_counter()
                whole = one_json_object(client, batch)
                batch_json_ms.append((time.perf_counter() - start) * 1e3)
                mismatched.update(mismatched_targets(whole, single_answers))
                server_timings.append({str(span): ms for span, ms in answer.timings_ms.items()})
                if products is not None:  # right after the round, at the machine's speed now
                    peaks.append(every_core_peak())
    finally:
        if own:
            server.stop()
    work = compiled_work(model, singles)
    singles_median = float(np.median(singles_ms))
    batch_median = float(np.median(batch_ms))
    batch_json_median = float(np.median(batch_json_ms))
    return {
        "server_settings": server_settings,
        "model": model.reference,
        "targets": len(targets),
        "num_samples": num_samples,
        "served_default": served_default,
        "rounds": rounds,
        "singles_median_ms": singles_median,
        "batch_median_ms": batch_median,
        "singles_over_batch": singles_median / batch_median,
        "batch_json_median_ms": batch_json_median,
        "singles_over_batch_json": singles_median / batch_json_median,
        "singles_ms": singles_ms,
        "batch_ms": batch_ms,
        "batch_json_ms": batch_json_ms,
        "server_batch_median_ms": _median_by_key(server_timings),
        "identical": not mismatched,
        "mismatched": sorted(mismatched),
        "cores": os.cpu_count() or 1,
        "singles_cpu_median_ms": _median_by_key(singles_cpu),
        "singles_server_median_ms": float(np.median(singles_server_ms)),
        "batch_cpu_median_ms": _median_by_key(batch_cpu),
        "compiled_work_ms": work,
        **(
            {}
            if products is None
            else {
                "network_products_per_target": products,
                "avx2_peak_every_core_per_s": float(np.median(peaks)),
            }
        ),
    }


def compiled_work(model: ServedModel, requests: Sequence[SmmRequest]) -> dict[str, float]:
    """What each target's answer costs that no sharing between a batch's targets removes,
    mean ms per target over `requests`, answered in process on one thread (the model
    reopened with one thread; warm): `compiled`, its compiled work, every call into
    `service.pipeline.native` (the kinematics of a compiled chain among them) and the flow
    network, which an answer equal to its single answer makes on exactly its own rows;
    `encode`, its answer's JSON encoding; `answer`, the whole answer (stages 1-6), whose
    rest, the pipeline's Python and numpy between those calls, is all a batch could share.
    Kinematics evaluated otherwise (ONNX, a model without a compiled chain) count in the
    rest, which can only understate the compiled work."""
    one = load_model(
        REPO_MODELS_DIR / model.manifest.model_id, threads=1, compiled_int8=Settings().compiled_int8
    )
    timer = KernelTimer()
    timed = replace(one, networks={name: timer.timed(f) for name, f in one.networks.items()})
    queries = [query_for_model(request, timed) for request in requests]
    run(timed, queries[0])  # warm-up
    answer_s = encode_s = 0.0
    with timer.timing():
        for query in queries:
            start = time.perf_counter()
            result = run(timed, query)
            answered = time.perf_counter()
            encode(smm_fields(timed, query, result))
            answer_s += answered - start
            encode_s += time.perf_counter() - answered
    count = max(len(queries), 1)
    return {
        "answer": answer_s * 1e3 / count,
        "compiled": timer.seconds * 1e3 / count,
        "encode": encode_s * 1e3 / count,
    }


def one_json_object(client: SmmClient, batch: SmmBatchRequest) -> SmmBatchResponse:
    """POST /smm/batch without asking for lines: the answer as one JSON object, parsed
    once it has all arrived."""
    body = batch.model_dump_json(exclude_none=True).encode()
    response = client.http.post(
        "/smm/batch", content=body, headers={"Content-Type": "application/json"}
    )
    response.raise_for_status()
    return SmmBatchResponse.model_validate_json(response.content)


class ProcessesCpu:
    """CPU time the server and this client process (every thread of each) spend from now:
    what a phase costs the machine's cores, whatever ran in parallel."""

    def __init__(self, server: LocalServer) -> None:
        self._server = server
        self._server_s, self._client_s = server.cpu_s(), time.process_time()

    def spent_ms(self) -> dict[str, float]:
        server_ms = (self._server.cpu_s() - self._server_s) * 1e3
        client_ms = (time.process_time() - self._client_s) * 1e3
        return {"server": server_ms, "client": client_ms, "total": server_ms + client_ms}


def _median_by_key(rounds: Sequence[dict[str, float]]) -> dict[str, float]:
    """Each key's median over the rounds (every round has the first one's keys)."""
    return {key: float(np.median([r[key] for r in rounds])) for key in rounds[0]}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    bundled = bundled_model_ids()
    parser.add_argument("--model", required=True, choices=bundled)
    parser.add_argument("--targets", type=int, default=64)
    parser.add_argument(
        "--num-samples", type=int, default=None, help="per target (default: the served default)"
    )
    parser.add_argument("--rounds", type=int, default=ROUNDS)
    parser.add_argument("--seed", type=int, default=TARGETS_SEED)
    args = parser.parse_args()
    model = load_model(REPO_MODELS_DIR / args.model, threads=1)
    limits = model.limits
    q_targets = uniform_configurations(limits, args.targets, args.seed)
    machine = Machine.now()
    result = batch_against_singles(
        model, q_targets, args.num_samples, args.rounds, progress=lambda s: print(s, flush=True)
    )
    result["machine"] = machine.ended().as_json()
    print(json.dumps(result, indent=1))
    print(
        f"{args.model}, {args.targets} targets x {result['num_samples']} samples, over HTTP: "
        f"{args.targets} single requests {result['singles_median_ms']:.0f} ms, one batch "
        f"{result['batch_median_ms']:.0f} ms as lines, {result['batch_json_median_ms']:.0f} ms as "
        f"one JSON object (median of {args.rounds}): the batch "
        f"{result['singles_over_batch']:.2f}x and {result['singles_over_batch_json']:.2f}x as "
        f"fast; answers identical: {result['identical']} "
        f"({Machine.from_json(result['machine']).describe()})"
    )
    cpu, network, compiled = cpu_bound(result), network_bound(result), compiled_bound(result)
    if cpu is not None:
        print(cpu_sentence(cpu))
    if compiled is not None:
        print(compiled_sentence(compiled))
    same_work = same_work_bound(result)
    if same_work is not None:
        print(same_work_sentence(same_work))
    if network is not None:
        print(network_sentence(network))


if __name__ == "__main__":
    main()
