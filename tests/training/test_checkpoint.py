"""checkpoint: what a run keeps on disk.

best.pt gives back the weights, the config and the command it was saved with; last.pt
reloads for a resumed run whose settings differ only where a resume may change them
(where and how fast it runs, the measurement after) and names every other difference.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from tests.support.tiny_training import TINY, tiny_planar_data, weights_equal
from training.checkpoint import LAST_FILE, load_best, load_state, save_best
from training.data import FlowData
from training.train import build_model, train


@pytest.fixture(scope="module")
def data() -> FlowData:
    return tiny_planar_data()


def test_best_checkpoint_round_trips_weights_and_provenance(data: FlowData, tmp_path: Path) -> None:
    result = train(TINY, data)
    save_best(tmp_path / "best.pt", result, TINY, command="smm-train --robot planar3r")
    best = load_best(tmp_path / "best.pt")
    assert best.config == TINY and best.command == "smm-train --robot planar3r"
    restored = best.result(build_model(best.config, data))
    assert restored.best_validation_loss == result.best_validation_loss
    assert restored.best_epoch == result.best_epoch
    assert weights_equal(restored.model, result.model)


def test_last_checkpoint_loads_with_other_run_settings_and_names_other_differences(
    data: FlowData, tmp_path: Path
) -> None:
    train(TINY, data, run_dir=tmp_path)
    faster = replace(TINY, threads=TINY.threads + 1, eval_targets=TINY.eval_targets + 1)
    state = load_state(tmp_path / LAST_FILE, faster)
    assert state.config == faster and state.next_epoch == TINY.epochs
    other = replace(TINY, learning_rate=5e-4, batch_size=64)
    with pytest.raises(ValueError, match=r"learning_rate \(0.001 there, 0.0005 now\)") as refused:
        load_state(tmp_path / LAST_FILE, other)
    assert "batch_size (128 there, 64 now)" in str(refused.value)
