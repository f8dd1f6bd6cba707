"""checkpoint: what a run keeps on disk.

best.pt gives back the weights, the config, the command, the commit and the processor it
was saved with (a best.pt from before runs stored them loads with none); last.pt
reloads for a resumed run whose settings differ only where a resume may change them
(where and how fast it runs, how often it checkpoints, the measurement after) and names
every other difference; a last.pt written before the mid-epoch and EMA fields still loads.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch

from tests.support.tiny_training import TINY, tiny_planar_data, weights_equal
from training.checkpoint import LAST_FILE, load_best, load_state, save_best
from training.data import FlowData
from training.train import build_model, train


@pytest.fixture(scope="module")
def data() -> FlowData:
    return tiny_planar_data()


def test_best_checkpoint_round_trips_weights_and_provenance(data: FlowData, tmp_path: Path) -> None:
    result = train(TINY, data)
    processor: dict[str, object] = {"cpu": "Some CPU", "generation": None, "cores": 2}
    command = "smm-train --robot planar3r"
    save_best(tmp_path / "best.pt", result, TINY, command, "abc123+dirty", processor)
    best = load_best(tmp_path / "best.pt")
    assert best.config == TINY and best.command == "smm-train --robot planar3r"
    assert best.git_commit == "abc123+dirty" and best.processor == processor
    restored = best.result(build_model(best.config, data))
    assert restored.best_validation_loss == result.best_validation_loss
    assert restored.best_epoch == result.best_epoch
    assert weights_equal(restored.model, result.model)
    payload = torch.load(tmp_path / "best.pt", weights_only=False)
    del payload["git_commit"], payload["processor"]  # as the runs before them wrote best.pt
    torch.save(payload, tmp_path / "older.pt")
    older = load_best(tmp_path / "older.pt")
    assert older.git_commit is None and older.processor is None


def test_last_checkpoint_loads_with_other_run_settings_and_names_other_differences(
    data: FlowData, tmp_path: Path
) -> None:
    train(TINY, data, run_dir=tmp_path)
    faster = replace(
        TINY, threads=TINY.threads + 1, eval_targets=TINY.eval_targets + 1, checkpoint_minutes=1.0
    )
    state = load_state(tmp_path / LAST_FILE, faster)
    assert state.config == faster and state.next_epoch == TINY.epochs
    other = replace(TINY, learning_rate=5e-4, batch_size=64)
    with pytest.raises(ValueError, match=r"learning_rate \(0.001 there, 0.0005 now\)") as refused:
        load_state(tmp_path / LAST_FILE, other)
    assert "batch_size (128 there, 64 now)" in str(refused.value)


def test_a_last_checkpoint_from_before_mid_epoch_and_ema_fields_loads_at_an_epoch_boundary(
    data: FlowData, tmp_path: Path
) -> None:
    """A last.pt without ema_model, epoch_start_generator, next_batch and epoch_loss_sum
    (and a config without the training options' fields) loads as a run between epochs, no
    average."""
    train(TINY, data, run_dir=tmp_path)
    payload = torch.load(tmp_path / LAST_FILE, weights_only=False)
    for name in ("ema_model", "epoch_start_generator", "next_batch", "epoch_loss_sum"):
        del payload[name]
    for name in ("ema_decay", "fresh_data", "architecture", "checkpoint_minutes"):
        del payload["config"][name]
    torch.save(payload, tmp_path / "old.pt")
    state = load_state(tmp_path / "old.pt", TINY)
    assert state.next_epoch == TINY.epochs and state.next_batch == 0
    assert state.ema_model is None and state.epoch_start_generator is None
