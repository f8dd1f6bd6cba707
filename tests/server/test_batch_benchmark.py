"""tools.batch_benchmark: K targets as one POST /smm/batch against K single POST /smm on a
real server; every batch answer is checked against its single answer, and a differing
answer is caught by index."""

from __future__ import annotations

import copy
from typing import Any

from service.models.registry import ServedModel
from tools.batch_benchmark import batch_against_singles, mismatched_targets
from training.evaluate.targets import uniform_configurations


def test_batch_against_singles_times_both_and_finds_the_answers_identical(
    planar3r: ServedModel,
) -> None:
    limits = planar3r.limits
    q_targets = uniform_configurations(limits, 3, seed=7)
    result = batch_against_singles(planar3r, q_targets, num_samples=100, rounds=2)
    assert result["identical"] is True and result["mismatched"] == []
    assert result["targets"] == 3 and result["num_samples"] == 100
    assert len(result["singles_ms"]) == len(result["batch_ms"]) == 2
    assert result["singles_median_ms"] > 0 and result["batch_median_ms"] > 0
    ratio = result["singles_median_ms"] / result["batch_median_ms"]
    assert result["singles_over_batch"] == ratio
    assert result["server_batch_median_ms"]["total"] > 0
    assert result["model"].startswith("planar3r-position@")


def test_a_batch_answer_that_differs_from_its_single_is_named() -> None:
    answer: dict[str, Any] = {
        "status": "ok",
        "components": [{"size": 3}],
        "timings_ms": {"total": 1.0},
    }
    singles = [answer, {**answer, "timings_ms": {"total": 2.0}}]
    batch: dict[str, Any] = {"results": [{"answer": copy.deepcopy(a)} for a in singles]}
    assert mismatched_targets(batch, singles) == []  # timings aside
    batch["results"][1]["answer"]["components"][0]["size"] = 4
    assert mismatched_targets(batch, singles) == [1]
    batch["results"][0]["answer"] = None  # not answered (deadline)
    assert mismatched_targets(batch, singles) == [0, 1]
