"""Time of one flow network call on one onnxruntime thread, on the service's threads and on
the compiled int8 layers.

    python -m tools.onnx_threads                       # every bundled model's served network
    python -m tools.onnx_threads --models planar3r-position --rows 128 512 1000

Each model's served flow network (its manifest's sampler) is opened twice as the service
opens it (workers that spin only while a call runs): with one intra-op thread, and with
the threads the service gives a session on this machine (`Settings`). At each row count the two take
turns, a block of calls each per round, so a load that comes and goes falls on both
alike. An int8 network is timed on the compiled layers as well (service/models/int8_mlp.py,
one thread, the exact product), where the processor has AMX, VNNI or AVX2: the service serves
it there (`Settings.compiled_int8`). Prints the median time per call of each, which is faster,
and what the service runs that row count on (every thread from `sessions.PARALLEL_MIN_ROWS`
rows). Compare figures only within one run (the CPU differs between machines).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from functools import partial

import numpy as np
import onnxruntime as ort

from service.config import Settings
from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from service.models.int8_mlp import CompiledVelocityField
from service.models.registry import int8_flow_here, open_flow
from service.models.sessions import FLOW_INPUTS, FLOW_OUTPUT, PARALLEL_MIN_ROWS, open_session
from training.machine import cpu_model

DEFAULT_ROWS = (64, 128, 256, 384, 512, 640, 768, 1000, 2000)


def block_ms(call: Callable[[], object], calls: int) -> float:
    """Mean time of one call over a block of `calls` calls, in ms."""
    start = time.perf_counter()
    for _ in range(calls):
        call()
    return (time.perf_counter() - start) / calls * 1e3


def feeds_of(session: ort.InferenceSession, rows: int, rng: np.random.Generator) -> dict:
    """Inputs like a sampler's: q_t ~ N(0, I), t ~ U(0, 1), condition ~ U(-1, 1)."""
    n, c = (session.get_inputs()[k].shape[1] for k in (0, 2))
    values = (
        rng.standard_normal((rows, n)),
        rng.uniform(0.0, 1.0, (rows, 1)),
        rng.uniform(-1.0, 1.0, (rows, c)),
    )
    return {name: v.astype(np.float32) for name, v in zip(FLOW_INPUTS, values, strict=True)}


def measure(model_id: str, rows: list[int], threads: int, rounds: int, calls: int) -> list[dict]:
    manifest = Manifest.model_validate_json(
        (REPO_MODELS_DIR / model_id / MANIFEST_FILE).read_text()
    )
    path = REPO_MODELS_DIR / model_id / manifest.defaults.sampler.file
    one, many = open_session(path, 1), open_session(path, threads)
    served = open_flow(path, threads, serial=False, compiled_int8=True)
    compiled = served if isinstance(served, CompiledVelocityField) else None
    rng = np.random.default_rng(0)
    results = []
    for count in rows:
        feeds = feeds_of(one, count, rng)
        runs: dict[str, Callable[[], object]] = {
            "one": partial(one.run, [FLOW_OUTPUT], feeds),
            "many": partial(many.run, [FLOW_OUTPUT], feeds),
        }
        if compiled is not None:
            runs["compiled"] = partial(compiled, **feeds)
        for call in runs.values():
            block_ms(call, 3)  # warm
        times: dict[str, list[float]] = {kind: [] for kind in runs}
        for _ in range(rounds):
            for kind, call in runs.items():
                times[kind].append(block_ms(call, calls))
        median = {kind: float(np.median(values)) for kind, values in times.items()}
        results.append(
            {
                "model": model_id,
                "network": manifest.defaults.sampler.file,
                "rows": count,
                "one_thread_ms": median["one"],
                "service_threads_ms": median["many"],
                "compiled_ms": median.get("compiled"),
                "served_on_every_thread": count >= PARALLEL_MIN_ROWS,
                "served_compiled": compiled is not None,
            }
        )
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    model_ids = sorted(p.parent.name for p in REPO_MODELS_DIR.glob(f"*/{MANIFEST_FILE}"))
    parser.add_argument("--models", nargs="+", choices=model_ids, default=model_ids)
    parser.add_argument("--rows", nargs="+", type=int, default=list(DEFAULT_ROWS))
    parser.add_argument("--rounds", type=int, default=15)
    parser.add_argument("--calls", type=int, default=10, help="calls per block")
    parser.add_argument("--json", help="write the figures here too")
    args = parser.parse_args()
    threads = Settings().onnx_threads_per_session
    results = [
        row
        for model_id in args.models
        for row in measure(model_id, args.rows, threads, args.rounds, args.calls)
    ]
    print(f"{cpu_model()}; service threads per session: {threads}; onnxruntime runs a call")
    print(f"of at least {PARALLEL_MIN_ROWS} rows on every thread, a smaller one on one; an int8")
    print(f"network is served on {int8_flow_here()} on this processor\n")
    print(
        f"| model | network | rows | 1 thread ms | {threads} threads ms | compiled ms | "
        "fastest | served on |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        kinds = {"1 thread": r["one_thread_ms"], f"{threads} threads": r["service_threads_ms"]}
        if r["compiled_ms"] is not None:
            kinds["compiled"] = r["compiled_ms"]
        fastest = min(kinds, key=lambda kind: kinds[kind])
        served = (
            "compiled"
            if r["served_compiled"]
            else f"{threads if r['served_on_every_thread'] else 1} thread(s)"
        )
        compiled_ms = "-" if r["compiled_ms"] is None else f"{r['compiled_ms']:.3f}"
        print(
            f"| {r['model']} | {r['network']} | {r['rows']} | {r['one_thread_ms']:.3f} | "
            f"{r['service_threads_ms']:.3f} | {compiled_ms} | {fastest} | {served} |"
        )
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(
                {"cpu": cpu_model(), "threads": threads, "results": results}, handle, indent=1
            )


if __name__ == "__main__":
    main()
