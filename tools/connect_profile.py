"""Where the connect stage's time goes: the compiled kernels against everything else.

    python -m tools.connect_profile --model iiwa14-pose --targets 20

Runs stages 1-4 on held-out targets (uniform configurations in the limits, their FK),
then stage 5 with every compiled kernel (`service.pipeline.native`: the task residual,
Newton steps, bordered solves, frames, clearances...) and the model's kinematics behind
timers, and prints per target the connect stage's wall time, the kernel calls inside it
and their time; then medians. What is left is the stage's own Python and numpy between
those calls. In process, on `--threads` row threads (the model's, in the benchmark):
with more than one, a kernel call's rows may be split over them and two calls run beside
the stage (`rows.Aside`); only the calls made on the stage's own thread are counted, the
ones beside it overlap it. `--repeats`: each target's stage timed that many times, its
least time and that run's kernels kept (the least is the machine's speed with the least
interference). Compare figures only within one run (the CPU, and what else runs on it,
differ between runs and machines).
"""

from __future__ import annotations

import argparse
import inspect
import json
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline import native
from service.pipeline.arrays import FloatArray
from service.pipeline.connect import connect
from service.pipeline.run import collision_of, correct_samples, encode, sample, space_of
from service.pipeline.targets import fields_reached
from service.pipeline.types import Query
from training.evaluate.targets import uniform_configurations


@dataclass
class KernelTimer:
    """Time and calls of the compiled kernels while it is entered: each public function of
    `service.pipeline.native` is wrapped (callers look them up on the module at call time),
    and any other compiled callable through `timed` (a flow network). A call made inside
    another timed call (a kernel's Python wrapper calling another) counts once, as part of
    the outer one."""

    calls: int = 0
    seconds: float = 0.0
    _owner: int | None = None
    _depth: int = 0

    def timed(self, kernel: Callable[..., Any]) -> Callable[..., Any]:
        """`kernel`, timed while the timer is entered, on the thread that entered it."""

        def call(*args: Any, **kwargs: Any) -> Any:
            if threading.get_ident() != self._owner or self._depth:
                return kernel(*args, **kwargs)
            self._depth += 1
            start = time.perf_counter()
            try:
                return kernel(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start
                self.calls += 1
                self._depth -= 1

        return call

    @contextmanager
    def timing(self) -> Iterator[None]:
        """Count the kernels called on this thread (those set aside run beside it)."""
        self._owner = threading.get_ident()
        originals = {
            name: getattr(native, name)
            for name in dir(native)
            if not name.startswith("_")
            and inspect.isfunction(getattr(native, name))
            and getattr(native, name).__module__ == native.__name__
        }
        for name, kernel in originals.items():
            setattr(native, name, self.timed(kernel))
        try:
            yield
        finally:
            for name, kernel in originals.items():
                setattr(native, name, kernel)
            self._owner = None


def queries_for(
    model: ServedModel, q_targets: FloatArray, num_samples: int | None = None
) -> list[Query]:
    """A query per row of q_targets (T, n): its FK as the target, seed i for target i, the
    model's defaults but `num_samples` (None: the model's)."""
    manifest = model.manifest
    queries = []
    for i, q in enumerate(q_targets):
        fk = model.kinematics(q[None])
        fields = fields_reached(manifest.task, fk.position_m[0], fk.rotation[0])
        queries.append(
            Query.for_model(
                manifest,
                position_m=fields.position_m,
                orientation_wxyz=fields.orientation_wxyz,
                axis=fields.axis,
                num_samples=num_samples,
                seed=i,
            )
        )
    return queries


def profile_connect(
    model: ServedModel, q_targets: FloatArray, num_samples: int | None = None, repeats: int = 1
) -> list[dict[str, float]]:
    """Per target (FK of each row of q_targets (T, n), seed i for target i): stages 1-4
    with the model's defaults at `num_samples` (None: the model's default), then stage 5
    with its kinematics behind a timer, `repeats` times (the least time kept)."""
    defaults = model.manifest.defaults
    rows: list[dict[str, float]] = []
    for i, query in enumerate(queries_for(model, q_targets, num_samples)):
        # Stages 1-4 as the pipeline runs them (service/pipeline/run.py).
        target = encode(model, query)
        space = space_of(model, target, query.tolerance, collision_of(model, query))
        correction = correct_samples(model, space, sample(model, query, target))
        acceptance = space.accept(correction)
        best: dict[str, float] | None = None
        for _ in range(repeats):
            timer = KernelTimer()
            with timer.timing():
                start = time.perf_counter()
                connection = connect(space, correction, acceptance, defaults.connectivity)
                connect_ms = (time.perf_counter() - start) * 1e3
            if best is None or connect_ms < best["connect_ms"]:
                best = {
                    "target": i,
                    "components": len(connection.components),
                    "connect_ms": round(connect_ms, 1),
                    "kernels_ms": round(timer.seconds * 1e3, 1),
                    "kernel_calls": timer.calls,
                }
        assert best is not None, "repeats must be at least 1"
        rows.append(best)
    return rows


def summarise(rows: list[dict[str, float]]) -> dict[str, float]:
    """Medians over the targets, and the connect stage's p95."""
    summary = {
        key: float(np.median([r[key] for r in rows]))
        for key in ("connect_ms", "kernels_ms", "kernel_calls")
    }
    summary["connect_p95_ms"] = float(np.percentile([r["connect_ms"] for r in rows], 95))
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    parser.add_argument("--model", default="iiwa14-pose")
    parser.add_argument("--targets", type=int, default=20)
    parser.add_argument("--seed", type=int, default=11)
    parser.add_argument("--num-samples", type=int, help="default: the model's num_samples")
    parser.add_argument("--threads", type=int, default=1, help="row threads (0: every core)")
    parser.add_argument("--repeats", type=int, default=1, help="timings per target, least kept")
    args = parser.parse_args()
    if args.repeats < 1 or args.threads < 0:
        parser.error("--repeats must be at least 1 and --threads at least 0")
    model = load_model(REPO_MODELS_DIR / args.model, threads=args.threads)
    limits = model.limits
    q_targets = uniform_configurations(limits, args.targets, args.seed)
    rows = profile_connect(model, q_targets, args.num_samples, args.repeats)
    for row in rows:
        print(json.dumps(row))
    print(json.dumps({"median": summarise(rows)}))


if __name__ == "__main__":
    main()
