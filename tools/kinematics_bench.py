"""Time of one kinematics call: the numpy chain kernel (chain.json) against kinematics.onnx.

    python -m tools.kinematics_bench --model iiwa14-pose

Both are opened from the model's files as the service opens them (onnxruntime with one
intra-op thread) and called on the same configurations, uniform in the joint limits. At
each batch size they take turns, a block of calls each per round, so a load that comes
and goes on a shared machine falls on both alike. Prints the median over rounds of the
time per call and per configuration, and the largest difference between the two
answers. Compare figures only within one run (the CPU differs between machines).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from service.manifest import CHAIN_FILE, KINEMATICS_FILE, REPO_MODELS_DIR
from service.models.chain import SerialChainKinematics
from service.models.sessions import OnnxKinematics, open_session
from service.pipeline.arrays import FloatArray
from service.pipeline.types import Kinematics
from training.machine import cpu_model


def block_seconds(kinematics: Kinematics, q: FloatArray, calls: int) -> float:
    """Mean time of one call over a block of `calls` calls."""
    start = time.perf_counter()
    for _ in range(calls):
        kinematics(q)
    return (time.perf_counter() - start) / calls


def max_difference(a: Kinematics, b: Kinematics, q: FloatArray) -> float:
    x, y = a(q), b(q)
    return max(
        float(np.max(np.abs(x.position_m - y.position_m))),
        float(np.max(np.abs(x.rotation - y.rotation))),
        float(np.max(np.abs(x.jacobian - y.jacobian))),
    )


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="iiwa14-pose")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 30, 200, 1000])
    parser.add_argument("--seconds", type=float, default=2.0, help="per batch size and method")
    parser.add_argument("--rounds", type=int, default=20)
    args = parser.parse_args(argv)

    model_dir = REPO_MODELS_DIR / args.model
    manifest = json.loads((model_dir / "manifest.json").read_text())
    joints = manifest["joints"]
    methods: dict[str, Kinematics] = {
        "chain.json": SerialChainKinematics.from_file(model_dir / CHAIN_FILE),
        "kinematics.onnx": OnnxKinematics(open_session(model_dir / KINEMATICS_FILE, threads=1)),
    }
    rng = np.random.default_rng(0)
    print(f"{args.model}, {len(joints['names'])} joints; CPU: {cpu_model()}; one thread")
    print(f"{'batch':>6} " + " ".join(f"{name + ' per call':>26}" for name in methods))
    for batch in args.batches:
        q = rng.uniform(joints["lower_rad"], joints["upper_rad"], (batch, len(joints["names"])))
        calls = {}
        for name, kinematics in methods.items():
            once = block_seconds(kinematics, q, 3)  # also warms it
            calls[name] = max(1, int(args.seconds / args.rounds / once))
        rounds: dict[str, list[float]] = {name: [] for name in methods}
        for _ in range(args.rounds):
            for name, kinematics in methods.items():
                rounds[name].append(block_seconds(kinematics, q, calls[name]))
        cells = []
        for times in rounds.values():
            seconds = float(np.median(times))
            cells.append(f"{seconds * 1e6:9.1f} us ({seconds * 1e6 / batch:6.2f} us/q)")
        print(f"{batch:>6} " + " ".join(f"{cell:>26}" for cell in cells))
    q = rng.uniform(joints["lower_rad"], joints["upper_rad"], (10_000, len(joints["names"])))
    difference = max_difference(methods["chain.json"], methods["kinematics.onnx"], q)
    print(f"max |chain.json - kinematics.onnx| over 10,000 configurations: {difference:.2g}")


if __name__ == "__main__":
    main()
