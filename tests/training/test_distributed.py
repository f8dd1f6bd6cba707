"""Distributed training: one model trained by two CPU processes (gloo) with DDP.

The shard function splits an epoch's order into disjoint, equal parts. Run by two processes
as torchrun starts them, `train` gives each process a disjoint half of every epoch's
shuffle (a new shuffle each epoch, the same one again on resume) and its own noise seed
(seed + rank); the processes end with bit-identical weights (DDP averaged the gradients)
and the same history; the validation loss is the full validation split's; only rank 0
writes last.pt and the log; a run stopped mid-epoch resumes with the same two processes to
the history and weights of a run never stopped, and one process is refused its last.pt by
a message naming both counts.

End to end, `python -m torch.distributed.run --nproc-per-node 2 --no-python smm-train train`
trains a tiny planar 3R model: each process reports its half, rank 0 alone writes one set of run
files and the export (flow.onnx, flow_int8.onnx, manifest recording two processes and the
torchrun command), and the served model's every configuration reaches the target.
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from service.manifest import Manifest
from service.models.registry import sha256_of
from tests.support.app import make_client
from tests.support.tiny_training import tiny_planar_data, weights_equal
from tests.support.two_processes import (
    STOP_AT,
    TWO,
    run_two_processes,
    train_whole_stopped_and_resumed,
)
from training.checkpoint import LAST_FILE, load_state
from training.distributed import Processes, shard
from training.evaluate.references.planar3r import planar3r_position
from training.run_log import LOG_FILE
from training.train import split, validation_loss

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("world_size", [1, 2, 3, 8])
def test_shards_are_disjoint_equal_and_cover_all_but_the_remainder(world_size: int) -> None:
    order = torch.randperm(101, generator=torch.Generator().manual_seed(0))
    parts = [shard(order, rank, world_size) for rank in range(world_size)]
    assert {len(p) for p in parts} == {101 // world_size}
    together = torch.cat(parts)
    assert len(set(together.tolist())) == len(together)  # disjoint
    assert set(together.tolist()) == set(order[: 101 - 101 % world_size].tolist())
    assert torch.equal(shard(order, 0, 1), order)


def test_validation_parts_cover_the_split_in_order() -> None:
    parts = [Processes(rank=r, world_size=3).part(10) for r in range(3)]
    assert [list(range(10))[p] for p in parts] == [[0, 1, 2], [3, 4, 5], [6, 7, 8, 9]]
    assert Processes().part(10) == slice(None)


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[dict[str, Any]]]:
    out = tmp_path_factory.mktemp("two")
    run_two_processes(train_whole_stopped_and_resumed, out)
    return out, [torch.load(out / f"rank{r}.pt", weights_only=False) for r in (0, 1)]


def test_each_process_trains_on_its_own_half_with_its_own_noise(
    two_runs: tuple[Path, list[dict[str, Any]]],
) -> None:
    _, ranks = two_runs
    whole = [[s for s in rank["seen"] if s["run"] == "whole"] for rank in ranks]
    assert [s["epoch"] for s in whole[0]] == [s["epoch"] for s in whole[1]] == [0, 1, 2]
    epochs = []
    for first, second in zip(*whole, strict=True):
        a, b = set(first["order"].tolist()), set(second["order"].tolist())
        assert len(a) == len(b) == 270 and not a & b and a | b == set(range(540))
        epochs.append(first["order"])
        assert (first["noise_seed"], second["noise_seed"]) == (TWO.seed, TWO.seed + 1)
    assert not torch.equal(epochs[0], epochs[1])  # a new shuffle each epoch
    for rank in ranks:  # the resumed run draws epochs 1 and 2 as the whole run did
        again = {s["epoch"]: s["order"] for s in rank["seen"] if s["run"] == "resumed"}
        for s in rank["seen"]:
            if s["run"] == "whole" and s["epoch"] in again:
                assert torch.equal(again[s["epoch"]], s["order"])


def test_the_processes_end_with_the_same_weights_and_history(
    two_runs: tuple[Path, list[dict[str, Any]]],
) -> None:
    """Different shards and noise, yet the same weights bit for bit: DDP averaged the
    gradients. Without it the processes would drift apart from the first step."""
    _, (first, second) = two_runs
    assert weights_equal(first["whole"].model, second["whole"].model)
    assert first["whole"].history == second["whole"].history
    assert len(first["whole"].history) == TWO.epochs


def test_the_validation_loss_is_the_whole_splits(
    two_runs: tuple[Path, list[dict[str, Any]]],
) -> None:
    """Each process measures half of the validation split; the recorded loss of the kept
    weights is what one process measures on all of it (same split, same noise)."""
    _, (first, _) = two_runs
    data = tiny_planar_data()
    generator = torch.Generator().manual_seed(TWO.seed)
    _, val_index = split(data, TWO.validation_fraction, generator)
    q_1, condition = data.q_1[val_index], data.condition[val_index]
    q_0 = torch.randn(q_1.shape, generator=generator)
    t = torch.rand(q_1.shape[0], 1, generator=generator)
    whole = first["whole"]
    measured = validation_loss(whole.model, q_1, condition, q_0, t)
    assert whole.best_validation_loss == pytest.approx(measured, rel=1e-5)


def test_only_rank_0_writes_the_run_directory(
    two_runs: tuple[Path, list[dict[str, Any]]],
) -> None:
    out, (first, second) = two_runs
    assert second["writes"] == {"save_state": 0, "write_log": 0}
    assert first["writes"]["save_state"] > 0 and first["writes"]["write_log"] > 0
    assert sorted(p.name for p in (out / "whole").iterdir()) == [
        "last.pt", "log.jsonl", "loss.png",
    ]  # fmt: skip
    lines = (out / "whole" / LOG_FILE).read_text().splitlines()
    assert [json.loads(line)["epoch"] for line in lines] == [0, 1, 2]


def test_a_run_stopped_mid_epoch_resumes_with_the_same_processes_to_the_same_weights(
    two_runs: tuple[Path, list[dict[str, Any]]],
) -> None:
    out, ranks = two_runs
    for rank in ranks:
        stopped = [s["epoch"] for s in rank["seen"] if s["run"] == "stopped"]
        assert stopped == [0, STOP_AT[0]]  # it did stop in epoch 1
        assert rank["resumed"].history == rank["whole"].history
        assert rank["resumed"].best_epoch == rank["whole"].best_epoch
        assert weights_equal(rank["resumed"].model, rank["whole"].model)
    # Another number of processes is refused, with both counts named.
    with pytest.raises(ValueError, match=r"a run of 2 training process\(es\), this run has 1"):
        load_state(out / "stopped" / LAST_FILE, replace(TWO, world_size=1))
    assert load_state(out / "stopped" / LAST_FILE, TWO).rank_generators is not None


def test_torchrun_trains_one_model_in_two_processes_that_is_exported_and_served(
    tmp_path: Path,
) -> None:
    models, runs = tmp_path / "models", tmp_path / "runs"
    arguments = [
        "--robot", "planar3r", "--task", "position",
        "--samples", "600", "--epochs", "2", "--hidden-width", "64", "--hidden-layers", "2",
        "--sweep-targets", "0", "--eval-targets", "4", "--eval-samples-per-target", "200",
        "--reflow-steps", "0", "--models-dir", str(models), "--runs-dir", str(runs),
    ]  # fmt: skip
    command = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
        "--no-python", str(Path(sys.executable).with_name("smm-train")), "train", *arguments,
    ]  # fmt: skip
    environment = {k: v for k, v in os.environ.items() if k not in ("RANK", "WORLD_SIZE")}
    result = subprocess.run(
        command, capture_output=True, text=True, timeout=300, cwd=REPO, env=environment
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-3000:]

    output = result.stdout + result.stderr
    for rank in (0, 1):  # 600 samples: 540 to train, 60 to validate, each halved
        expected = f"process {rank} of 2: 270 of 540 training samples per epoch, 30 of 60"
        assert expected in output
    assert output.count("labelling 600 configurations") == 1  # said by rank 0 alone

    run_dir = runs / "planar3r-position"
    assert sorted(p.name for p in run_dir.iterdir()) == [
        "best.pt", "history.json", "last.pt", "log.jsonl", "loss.png",
    ]  # fmt: skip
    assert len((run_dir / LOG_FILE).read_text().splitlines()) == 2
    assert sorted(p.name for p in models.iterdir()) == ["planar3r-position", "robots"]

    model_dir = models / "planar3r-position"
    manifest = Manifest.model_validate_json((model_dir / "manifest.json").read_text())
    assert manifest.training.config["world_size"] == 2
    assert manifest.training.command == shlex.join(
        ["torchrun", "--nproc-per-node", "2", "--no-python", "smm-train", "train", *arguments]
    )
    assert (manifest.training.samples, manifest.training.epochs) == (600, 2)
    assert sorted(manifest.files) == [
        "chain.json", "flow.onnx", "flow_int8.onnx", "kinematics.onnx",
    ]  # fmt: skip
    for name, digest in manifest.files.items():
        assert sha256_of(model_dir / name) == digest

    target = [1.2, -0.8]
    with make_client(models) as client:
        body = {"robot": "planar3r", "task": "position", "target": {"position": target}}
        response = client.post("/smm", json={**body, "num_samples": 1000, "seed": 1})
    assert response.status_code == 200, response.text
    answer = response.json()
    q = np.array([q for c in answer["components"] for q in c["configurations"]]).reshape(-1, 3)
    assert len(q) > 0
    assert np.all(np.linalg.norm(planar3r_position(q) - target, axis=1) <= 1e-6)
