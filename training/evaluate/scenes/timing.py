"""The service's pipeline time for one target, asked four ways back to back (so that
every way meets the machine in the same state, target by target): in its random scene,
with self-collision only (as served without obstacles), with nothing checked, and in a
scene of exactly `TIMING_OBSTACLES` boxes (the timing goal's scene)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.collision.scene import Obstacle
from service.pipeline.run import run
from service.pipeline.targets import TargetFields
from service.pipeline.types import Query, SmmResult

TIMING_OBSTACLES = 10
WAYS = ("scene", "self_only", "nothing_checked", f"{TIMING_OBSTACLES}_boxes")


def query_for(
    model: ServedModel,
    target: TargetFields,
    obstacles: Sequence[Obstacle],
    check_self: bool,
    margin_m: float,
    seed: int,
) -> Query:
    """The query a client sends for this target and scene, with the model's defaults."""
    return Query.for_model(
        model.manifest, position_m=target.position_m, orientation_wxyz=target.orientation_wxyz,
        axis=target.axis, seed=seed, obstacles=obstacles, check_self=check_self,
        margin_m=margin_m,
    )  # fmt: skip


def time_ways_ms(
    model: ServedModel,
    target: TargetFields,
    scene: Sequence[Obstacle],
    timing_scene: Sequence[Obstacle],
    margin_m: float,
    seed: int,
) -> tuple[dict[str, float], dict[str, SmmResult]]:
    """The pipeline's total time (ms) of each way in WAYS, in that order, and the answers."""
    asked = {
        WAYS[0]: (scene, True),
        WAYS[1]: ((), True),
        WAYS[2]: ((), False),
        WAYS[3]: (timing_scene, True),
    }
    times, answers = {}, {}
    for way, (obstacles, check_self) in asked.items():
        query = query_for(model, target, obstacles, check_self, margin_m, seed)
        answers[way] = run(model, query)
        times[way] = answers[way].timings.total_ms
    return times, answers


def median_p95(values: Sequence[float]) -> dict[str, float]:
    return {"median": float(np.median(values)), "p95": float(np.percentile(values, 95))}
