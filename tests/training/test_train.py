"""train: the loop keeps the best validation loss, and a run stopped after an epoch resumes
from last.pt to exactly the weights of a run that never stopped (or is refused when there is
no last.pt)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.tiny_training import TINY, tiny_planar_data, weights_equal
from training import train as train_module
from training.checkpoint import LAST_FILE
from training.config import TrainConfig
from training.data import FlowData
from training.train import train


@pytest.fixture(scope="module")
def data() -> FlowData:
    return tiny_planar_data()


def test_the_best_epoch_is_the_one_with_the_lowest_validation_loss(data: FlowData) -> None:
    result = train(TINY, data)
    losses = [row["validation_loss"] for row in result.history]
    assert [row["epoch"] for row in result.history] == [0, 1, 2]
    assert result.best_epoch == losses.index(min(losses))
    assert result.best_validation_loss == min(losses)


def test_a_stopped_run_resumes_to_the_weights_of_an_uninterrupted_one(
    data: FlowData, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    uninterrupted = train(TINY, data, run_dir=tmp_path / "whole")

    run_dir = tmp_path / "stopped"
    real_save = train_module.save_state

    def save_then_stop(path: Path, state: object) -> None:
        real_save(path, state)  # type: ignore[arg-type]
        raise KeyboardInterrupt  # the session ends right after epoch 0 was saved

    monkeypatch.setattr(train_module, "save_state", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        train(TINY, data, run_dir=run_dir)
    monkeypatch.undo()
    assert (run_dir / LAST_FILE).is_file()

    resumed = train(TINY, data, run_dir=run_dir, resume=True)
    assert [row["epoch"] for row in resumed.history] == [0, 1, 2]
    assert resumed.history == uninterrupted.history
    assert resumed.best_epoch == uninterrupted.best_epoch
    assert weights_equal(resumed.model, uninterrupted.model)


def test_resume_refuses_a_run_written_with_other_settings(data: FlowData, tmp_path: Path) -> None:
    train(TINY, data, run_dir=tmp_path)
    other = TrainConfig(**{**TINY.as_dict(), "learning_rate": 5e-4})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"learning_rate \(0.001 there, 0.0005 now\)"):
        train(other, data, run_dir=tmp_path, resume=True)
    with pytest.raises(ValueError, match="nothing to resume"):
        train(TINY, data, run_dir=tmp_path / "empty", resume=True)
