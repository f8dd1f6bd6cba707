"""How far onnxruntime's int8 flow networks are from the exact quantised network on this
processor, and so why the service evaluates them on its compiled layers.

    python -m tools.int8_exactness                 # every bundled int8 network, 500 rows
    python -m tools.int8_exactness --json docs/benchmark/int8-exactness.json

Each bundled int8 network is called on a sampler's kind of rows (q_t ~ N(0, I), the
condition ~ U(-1, 1), one t per call as an Euler step has, at t = 0, 0.25, 0.5 and 0.75)
by onnxruntime's session and by the compiled layers (service/models/int8_mlp.py, whose
integer product is exact on every kernel; tests/service/models/test_int8_mlp.py pins it to
numpy's int64 product). Prints, per network, the largest difference in a velocity, the
largest velocity, and the share of rows that differ by more than 1e-5 of their row's
largest velocity (float32 round-off at that scale; an exact product differs by none).

On a processor with VNNI or AMX, onnxruntime's product is exact too and every figure is 0.
On AVX2 alone, MLAS multiplies u8 by s8 with vpmaddubsw, whose int16 sums of two products
saturate: the figures say how much of a sampler's rows that moves.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from service.models.int8_mlp import CompiledVelocityField, best_kernel
from service.models.registry import INT8_FLOW_FILES
from service.models.sessions import FLOW_INPUTS, FLOW_OUTPUT, open_session
from training.machine import Machine, cpu_flags, cpu_model

# MLAS's u8 x s8 product runs on VNNI (vpdpbusd) or AMX where the processor has them, both
# exact; on AVX2 alone (and AVX-512 without VNNI) on vpmaddubsw, which saturates.
EXACT_ONNXRUNTIME_FLAGS = frozenset({"avx512_vnni", "avx_vnni", "amx_int8"})
TIMES = (0.0, 0.25, 0.5, 0.75)  # one t per call, as a sampler's Euler steps
ROW_ROUND_OFF = 1e-5  # of a row's largest |velocity|: float32 round-off at the row's scale


def onnxruntime_product_exact() -> bool:
    """Whether onnxruntime's int8 product is exact on this processor (it has VNNI or AMX)."""
    return bool(cpu_flags() & EXACT_ONNXRUNTIME_FLAGS)


def int8_networks() -> list[Path]:
    """Every bundled model's int8 flow network that its manifest lists."""
    paths = []
    for manifest_path in sorted(REPO_MODELS_DIR.glob(f"*/{MANIFEST_FILE}")):
        manifest = Manifest.model_validate_json(manifest_path.read_bytes())
        for name in sorted(manifest.files):
            if name in INT8_FLOW_FILES:
                paths.append(manifest_path.parent / name)
    return paths


def measure(path: Path, rows: int, seed: int) -> dict[str, object]:
    """onnxruntime against the exact network at `rows` rows, one call per t in TIMES."""
    session = open_session(path, 1)
    exact = CompiledVelocityField.open(path)
    n, c = (session.get_inputs()[k].shape[1] for k in (0, 2))
    rng = np.random.default_rng(seed)
    largest_difference = largest_velocity = 0.0
    rows_differing = 0
    for t in TIMES:
        values = (
            rng.standard_normal((rows, n)),
            np.full((rows, 1), t),
            rng.uniform(-1.0, 1.0, (rows, c)),
        )
        feeds = {k: v.astype(np.float32) for k, v in zip(FLOW_INPUTS, values, strict=True)}
        (theirs,) = session.run([FLOW_OUTPUT], feeds)  # (rows, n)
        ours = exact(**feeds)  # (rows, n)
        difference = np.abs(theirs - ours).max(axis=1)  # (rows,)
        scale = np.abs(ours).max(axis=1)  # (rows,)
        rows_differing += int((difference > ROW_ROUND_OFF * scale).sum())
        largest_difference = max(largest_difference, float(difference.max()))
        largest_velocity = max(largest_velocity, float(scale.max()))
    return {
        "model": path.parent.name,
        "network": path.name,
        "rows": rows * len(TIMES),
        "largest_difference": largest_difference,
        "largest_velocity": largest_velocity,
        "rows_differing_share": rows_differing / (rows * len(TIMES)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", type=int, default=500, help="rows per call")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, help="write the figures here too")
    args = parser.parse_args()
    machine = Machine.now()
    results = [measure(path, args.rows, args.seed) for path in int8_networks()]
    exact = "exact" if onnxruntime_product_exact() else "saturating (no VNNI or AMX)"
    print(f"{cpu_model()}; onnxruntime's int8 product here: {exact}; compiled layers on "
          f"{best_kernel()}; {args.rows} rows per call, t in {TIMES}\n")  # fmt: skip
    print("| model | network | largest difference | largest velocity | rows differing |")
    print("|---|---|---|---|---|")
    for r in results:
        print(
            f"| {r['model']} | {r['network']} | {r['largest_difference']:.3g} | "
            f"{r['largest_velocity']:.3g} | {100 * float(r['rows_differing_share']):.1f} % |"  # type: ignore[arg-type]
        )
    if args.json:
        report = {
            "command": " ".join(["python -m tools.int8_exactness", *sys.argv[1:]]),
            "machine": machine.ended().as_json(),
            "kernel": best_kernel(),
            "onnxruntime_exact": onnxruntime_product_exact(),
            "rows_per_call": args.rows,
            "times": list(TIMES),
            "results": results,
        }
        args.json.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
