"""The least time the served int8 networks can take on this processor's AVX2 kernel, and
how near the compiled layers come to it.

    python -m tools.network_floor                      # every bundled int8 network
    python -m tools.network_floor --json docs/benchmark/network-floor.json

An int8 network's exact product on AVX2 (service/models/int8_mlp.c) is vpmaddwd on the
operands widened to int16: 16 integer products an instruction, the kernel's one
multiplication. `int8_mlp.avx2_product_peak` runs vpmaddwd and nothing else on one core
and on every core at once: no layer can multiply faster here. A network needs its layers'
k x n products a row (padding aside), so its products over that rate is the least time any
AVX2 kernel can take, whatever else it does better.

Per bundled model whose served sampler is int8, in rounds that interleave the peak probe
with the compiled layers on AVX2 (one thread, 1000 rows), so a machine whose speed moves
moves both: the products a row, the layers' median time and their share of the peak (the
efficiency), and the floor of the default request's network work: its Euler steps'
evaluations of its rows (the manifest's num_samples; its first round's rows where it draws
in rounds, the least a request evaluates) over every core's peak, beside the time goal it
is read against (tools.goals). On a processor with AMX the service serves the AMX kernel,
which this floor does not bound; the report says which kernel is served.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from service.models.int8_mlp import CompiledVelocityField, avx2_product_peak, best_kernel
from service.models.registry import ServedModel
from tools.goals import GOAL_NUM_SAMPLES, GOALS
from training.machine import Machine

ROWS = 1000  # rows of the timed call: the per-row cost is flat from a few hundred
ROUNDS = 9  # each round: the peak probe, then CALLS calls of the layers
CALLS = 5
PROBE_S = 0.1
PEAK_PROBE_S = 0.2  # the every-core probe a benchmark runs after a model's or a round's runs


def served_int8(manifest: Manifest) -> str | None:
    """The file of the model's served sampler where it is an int8 network, else None."""
    sampler = manifest.defaults.sampler
    return sampler.file if sampler.precision == "int8" else None


def least_rows(manifest: Manifest, num_samples: int | None = None) -> int:
    """The rows a request of `num_samples` (None: the default) evaluates at least at each
    Euler step: num_samples, or one round's where the model draws in rounds."""
    asked = manifest.defaults.num_samples if num_samples is None else num_samples
    return min(asked, manifest.defaults.sampler.round_samples or asked)


def least_products(
    manifest: Manifest, products_per_row: int, num_samples: int | None = None
) -> int:
    """The integer products a request's network work needs at least: its Euler steps'
    evaluations of its least rows."""
    return manifest.defaults.sampler.steps * least_rows(manifest, num_samples) * products_per_row


def avx2_network_products(model: ServedModel, num_samples: int) -> int | None:
    """The integer products each target's network work needs where this processor serves
    the model's int8 network on the AVX2 kernel (no exact AVX2 kernel multiplies faster
    than vpmaddwd alone), else None (AMX, onnxruntime or float32)."""
    network = model.networks.get(model.manifest.defaults.sampler.file)
    if not isinstance(network, CompiledVelocityField) or network.kernel != "avx2":
        return None
    return least_products(model.manifest, network.layers.products_per_row, num_samples)


def every_core_peak(seconds: float = PEAK_PROBE_S) -> float:
    """The AVX2 product's peak on every core of this machine at once, products a second."""
    return avx2_product_peak(seconds, os.cpu_count() or 1)


def measure(model_dir: Path, rounds: int, seed: int) -> dict[str, Any]:
    """The layers on AVX2 against the AVX2 peak, interleaved, for one model."""
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    file = served_int8(manifest)
    assert file is not None
    field = CompiledVelocityField.open(model_dir / file, kernel="avx2")
    network = field.layers
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((ROWS, network.width_in)).astype(np.float32)  # (ROWS, k)
    network.forward(x, "avx2", 1)  # warm: scratch and caches
    products = network.products_per_row * ROWS
    peaks, calls_s, efficiencies = [], [], []  # by round
    for _ in range(rounds):
        peak = avx2_product_peak(PROBE_S, threads=1)
        start = time.perf_counter()
        for _ in range(CALLS):
            network.forward(x, "avx2", 1)
        call_s = (time.perf_counter() - start) / CALLS
        peaks.append(peak)
        calls_s.append(call_s)
        efficiencies.append(products / call_s / peak)
    return {
        "model": model_dir.name,
        "network": file,
        "products_per_row": network.products_per_row,
        "rows": ROWS,
        "call_ms": float(np.median(calls_s)) * 1e3,
        "peak_one_core_per_s": float(np.median(peaks)),
        # each round's layers against that round's peak: a speed that moves moves both
        "efficiency": float(np.median(efficiencies)),
        "evaluations": manifest.defaults.sampler.steps,
        "least_rows": least_rows(manifest),
        "least_rows_goal_n": least_rows(manifest, GOAL_NUM_SAMPLES),
    }


def with_floor(result: dict[str, Any], every_core_per_s: float) -> dict[str, Any]:
    """`result` with the floor of its default request's network work on every core, and at
    the goals' N (its least rows there: one round's where it draws in rounds), beside its
    time goal (None for a model without one)."""
    products = result["evaluations"] * result["products_per_row"]  # a row, every step
    goal = {model: ms for model, ms, _ in GOALS}.get(result["model"])
    return {
        **result,
        "floor_ms": products * result["least_rows"] / every_core_per_s * 1e3,
        "floor_goal_n_ms": products * result["least_rows_goal_n"] / every_core_per_s * 1e3,
        "goal_ms": goal,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", nargs="*", help="bundled model ids (default: every int8 one)")
    parser.add_argument("--rounds", type=int, default=ROUNDS)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, help="write the figures here too")
    args = parser.parse_args()
    machine = Machine.now()
    cores = os.cpu_count() or 1
    dirs = sorted(p.parent for p in REPO_MODELS_DIR.glob(f"*/{MANIFEST_FILE}"))
    chosen = [
        d
        for d in dirs
        if (not args.models or d.name in args.models)
        and served_int8(Manifest.model_validate_json((d / MANIFEST_FILE).read_bytes()))
    ]
    measured = [measure(d, args.rounds, args.seed) for d in chosen]
    every_core = float(np.median([every_core_peak(PROBE_S) for _ in range(args.rounds)]))
    results = [with_floor(r, every_core) for r in measured]
    print(
        f"{Machine.from_json(machine.ended().as_json()).describe()}; served kernel "
        f"{best_kernel()}; AVX2 product peak {every_core / 1e9:.1f} G/s on {cores} cores\n"
    )
    print("| model | products a row | layers ms (1000 rows) | of the peak | floor ms | goal ms |")
    print("|---|---|---|---|---|---|")
    for r in results:
        print(
            f"| {r['model']} | {r['products_per_row']:,} | {r['call_ms']:.2f} | "
            f"{r['efficiency']:.0%} | {r['floor_ms']:.1f} | {r['goal_ms'] or '-'} |"
        )
    if args.json:
        report = {
            "command": " ".join(["python -m tools.network_floor", *sys.argv[1:]]),
            "machine": machine.ended().as_json(),
            "served_kernel": best_kernel(),
            "cores": cores,
            "peak_every_core_per_s": every_core,
            "results": results,
        }
        args.json.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
