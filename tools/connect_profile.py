"""Where the connect stage's time goes: kinematics evaluations against everything else.

    python -m tools.connect_profile --model iiwa14-pose --targets 20

Runs stages 1-4 on held-out targets (uniform configurations in the limits, their FK),
then stage 5 with the model's kinematics behind a timer, and prints per target the
connect stage's wall time, the kinematics calls and configurations evaluated inside it
and their time; then medians. One thread, in process. Compare figures only within one
run (the CPU, and what else runs on it, differ between runs and machines).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, replace

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.arrays import FloatArray
from service.pipeline.connect import connect
from service.pipeline.fibre import Fibre
from service.pipeline.run import collision_of, correct_samples, encode, sample, space_of
from service.pipeline.types import Kinematics, KinematicsResult, Query
from training.evaluate.served import orientation_wxyz
from training.evaluate.targets import uniform_configurations


@dataclass
class TimedKinematics:
    inner: Kinematics
    calls: int = 0
    configurations: int = 0
    seconds: float = 0.0

    def __call__(self, q_rad: FloatArray) -> KinematicsResult:
        start = time.perf_counter()
        result = self.inner(q_rad)
        self.seconds += time.perf_counter() - start
        self.calls += 1
        self.configurations += len(q_rad)
        return result


def profile_connect(
    model: ServedModel, q_targets: FloatArray, num_samples: int | None = None
) -> list[dict[str, float]]:
    """Per target (FK of each row of q_targets (T, n), seed i for target i): stages 1-4
    with the model's defaults at `num_samples` (None: the model's default), then stage 5
    with its kinematics behind a timer."""
    manifest, defaults = model.manifest, model.manifest.defaults
    rows: list[dict[str, float]] = []
    for i, q in enumerate(q_targets):
        fk = model.kinematics(q[None])
        query = Query.for_model(
            manifest,
            position_m=fk.position_m[0, manifest.task.position_axes].tolist(),
            orientation_wxyz=orientation_wxyz(fk.rotation[0])
            if manifest.task.orientation
            else None,
            num_samples=num_samples,
            seed=i,
        )
        # Stages 1-4 as the pipeline runs them (service/pipeline/run.py).
        target = encode(model, query)
        space = space_of(model, target, query.tolerance, collision_of(model, query))
        correction = correct_samples(model, space, sample(model, query, target))
        acceptance = space.accept(correction)
        timed = TimedKinematics(model.kinematics)
        timed_space = replace(space, fibre=Fibre(target, manifest.task, timed, defaults.damping))
        start = time.perf_counter()
        connection = connect(timed_space, correction, acceptance, defaults.connectivity)
        connect_ms = (time.perf_counter() - start) * 1e3
        rows.append(
            {
                "target": i,
                "components": len(connection.components),
                "connect_ms": round(connect_ms, 1),
                "kinematics_ms": round(timed.seconds * 1e3, 1),
                "kinematics_calls": timed.calls,
                "configurations_evaluated": timed.configurations,
            }
        )
    return rows


def summarise(rows: list[dict[str, float]]) -> dict[str, float]:
    """Medians over the targets, and the connect stage's p95."""
    summary = {
        key: float(np.median([r[key] for r in rows]))
        for key in ("connect_ms", "kinematics_ms", "kinematics_calls", "configurations_evaluated")
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
    args = parser.parse_args()
    model = load_model(REPO_MODELS_DIR / args.model, threads=1)
    limits = model.limits
    q_targets = uniform_configurations(limits, args.targets, args.seed)
    rows = profile_connect(model, q_targets, args.num_samples)
    for row in rows:
        print(json.dumps(row))
    print(json.dumps({"median": summarise(rows)}))


if __name__ == "__main__":
    main()
