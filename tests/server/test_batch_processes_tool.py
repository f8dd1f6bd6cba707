"""The batch on threads against the batch on processes (`python -m tools.batch_processes`).

- The command, on planar 3R targets, answers them one after another, on the service's
  batch threads and on as many forked processes, and records each one's ms per target
  with the processes' answers checked equal to the threads' (none differ).
- The targets are the batch benchmark's (target i with seed i, at the served default N),
  and an answer's digest leaves out its timings only: the same query answered alone and in
  a batch has one digest, another target another.
- The sentence the console and the speed page print is the record's arithmetic.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from service.manifest import REPO_MODELS_DIR
from service.models.registry import load_model
from service.pipeline.batch import run_batch
from service.pipeline.run import run
from tools.batch_bounds import processes_sentence
from tools.batch_processes import answer_digest, batch_queries

ROOT = Path(__file__).resolve().parents[2]
MODEL = "planar3r-position"


def test_the_command_times_threads_and_processes_with_the_same_answers(tmp_path: Path) -> None:
    out = tmp_path / "record.json"
    command = [
        sys.executable, "-m", "tools.batch_processes", "--model", MODEL, "--targets", "5",
        "--processes", "2", "--rounds", "1", "--json", str(out),
    ]  # fmt: skip
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    record = json.loads(out.read_text())
    assert record["targets"] == 5 and record["processes"] == 2 and record["rounds"] == 1
    assert record["mismatched"] == []
    assert record["model"].startswith(f"{MODEL}@")
    manifest = load_model(REPO_MODELS_DIR / MODEL, threads=1).manifest
    assert record["num_samples"] == manifest.defaults.num_samples
    for key in ("one_after_another", "threads", "processes"):
        assert record[f"{key}_ms_per_target"] > 0
    assert record["command"].startswith("python -m tools.batch_processes --model planar3r")
    assert processes_sentence(record) in done.stdout


def test_the_targets_are_the_batch_benchmarks_and_a_digest_leaves_out_only_timings() -> None:
    model = load_model(REPO_MODELS_DIR / MODEL, threads=1)
    queries = batch_queries(model, 3)
    assert [q.seed for q in queries] == [0, 1, 2]
    assert {q.num_samples for q in queries} == {model.manifest.defaults.num_samples}
    alone = [answer_digest(model, q, run(model, q)) for q in queries]
    batch = run_batch(model, queries, threads=2)
    in_batch = [answer_digest(model, q, r) for q, r in zip(queries, batch.results, strict=True)]
    assert in_batch == alone  # timings differ between the two; the answers do not
    assert len(set(alone)) == 3  # each target its own answer


def test_the_sentence_is_the_records_arithmetic() -> None:
    record = {
        "targets": 4, "model": "m@0", "num_samples": 300, "threads": 2, "processes": 2,
        "one_after_another_ms_per_target": 12.0, "threads_ms_per_target": 10.0,
        "processes_ms_per_target": 8.0, "mismatched": [],
    }  # fmt: skip
    sentence = processes_sentence(record)
    assert "12.0 ms a target one after another, 10.0 ms on the service's 2 batch threads" in (
        sentence
    )
    assert "(1.20x), 8.0 ms on 2 processes (1.50x), with the same answers" in sentence
    assert "The threads take 1.25x the processes' time: 20% of the threads' batch" in sentence
    differing = processes_sentence({**record, "mismatched": [3]})
    assert "with answers differing on targets [3]" in differing
