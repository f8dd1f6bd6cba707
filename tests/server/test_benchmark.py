"""tools.benchmark: the command writes a report (JSON and Markdown) with every configuration
for every size (the float32 network beside an int8 default, the base flow beside a reflowed
one), over HTTP too, whose figures
are the evaluation's (planar 3R: the count against the closed form); random-restart DLS is
run to at least the service's number of valid configurations per target; a batch of
targets against its single requests, with identical answers, in the same report (when a
figure is worse: tests/training/evaluate/test_judge.py), with where the batch's time goes
per target and the ratio its sampling and transport alone leave."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from service.models.registry import ServedModel
from tools.benchmark import (
    BASE,
    FLOAT32,
    PAPER,
    RESTART,
    SERVICE,
    batch_profile,
    restarts_to_match,
)
from training.evaluate.targets import uniform_configurations
from training.export import git_commit

ROOT = Path(__file__).resolve().parents[2]


def test_the_command_writes_every_configuration_and_size(tmp_path: Path) -> None:
    command = [
        sys.executable, "-m", "tools.benchmark", "--models", "planar3r-position",
        "--sizes", "100", "200", "--targets", "2", "--out", str(tmp_path),
        "--batch-model", "planar3r-position", "--batch-targets", "3",
    ]  # fmt: skip
    subprocess.run(command, cwd=ROOT, check=True, capture_output=True, timeout=600)
    report = json.loads((tmp_path / "benchmark.json").read_text())
    entry = report["models"]["planar3r-position"]
    assert set(entry["sizes"]) == {"100", "200"}
    # The float32 network beside the service's own where the defaults serve int8, and the
    # base flow beside a reflowed sampler.
    names = [SERVICE, PAPER, RESTART] + ([FLOAT32] if entry["sampler_precision"] == "int8" else [])
    names += [BASE] if entry["sampler_flow"] == "reflow" else []
    for n, row in entry["sizes"].items():
        assert set(row) == {*names, "http"}
        for name in names:
            run = row[name]
            assert 0 < run["median_ms"] <= run["p95_ms"]
            assert run["figures"]["count_right"] == 1.0  # the closed form's count, both targets
            assert run["valid_configurations_mean"] <= (int(n) if name != RESTART else np.inf)
        assert (
            row[RESTART]["valid_configurations_mean"] >= row[SERVICE]["valid_configurations_mean"]
        )
        assert row["http"]["median_ms"] > 0
    text = (tmp_path / "benchmark.md").read_text()
    # every configuration and HTTP, at 2 sizes
    assert text.count("| planar3r-position |") == 2 * len(names) + 2
    assert report["machine"]["cores"] >= 1
    assert report["git_commit"] == git_commit() and f"at commit {git_commit()} on " in text
    # The batch against its singles, by default and sampling ahead: the same answers.
    for key, threads in (("batch", {}), ("batch_sampling_ahead", {"batch_sampling_threads": 1})):
        batch = report[key]
        assert batch["targets"] == 3 and batch["identical"] and batch["mismatched"] == []
        assert batch["server_settings"] == threads
        assert batch["singles_over_batch"] == pytest.approx(
            batch["singles_median_ms"] / batch["batch_median_ms"]
        )
    assert text.count("| default (`SMM_BATCH_SAMPLING_THREADS=0`) |") == 1
    assert text.count("| sampling ahead on the other core") == 1
    assert text.count("Where the default batch's time goes") == 1


def test_thebatch_profile_is_per_target_with_the_floor_of_sampling_and_transport() -> None:
    batch = {
        "targets": 4, "batch_median_ms": 80.0, "singles_median_ms": 240.0,
        "server_batch_median_ms": {"sample": 40.0, "correct": 8.0, "connect": 12.0,
                                   "summarise": 4.0, "total": 64.0},
    }  # fmt: skip
    lines = batch_profile(batch)
    # per target: singles 60, batch 20, stages 10 / 2 / 3 / 1, outside (80 - 64) / 4 = 4
    assert "| 60.0 | 20.0 | 10.0 | 2.0 | 3.0 | 1.0 | 4.0 |" in lines
    # sampling 10 + outside 4 = 14 ms: at most 60 / 14 = 4.3x
    assert any("14.0 ms per target: at most 4.3x the singles" in line for line in lines)


def test_restarts_reach_the_valid_count_asked_for(planar3r: ServedModel) -> None:
    lower, upper, _ = planar3r.manifest.joints.arrays()
    q_targets = uniform_configurations(lower, upper, 2, seed=7)
    timed = restarts_to_match(planar3r, q_targets, valid=[80, 120], num_samples=40)
    assert [a.kept >= wanted for a, wanted in zip(timed.answers, [80, 120], strict=True)] == [
        True,
        True,
    ]
