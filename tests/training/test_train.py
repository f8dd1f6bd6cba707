"""train: the loop keeps the best validation loss; a run stopped after an epoch or in the
middle of one resumes from last.pt to exactly the weights of a run that never stopped (or
is refused when there is no last.pt); the weight average is what is validated and kept;
fresh data gives each epoch new FK-consistent pairs; log.jsonl and loss.png follow the
history."""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import replace
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
import torch

from tests.support.tiny_training import TINY, tiny_planar_data, weights_equal
from training import train as train_module
from training.checkpoint import LAST_FILE, RunState
from training.config import TrainConfig
from training.data import FlowData, FlowPairs
from training.ema import WeightAverage
from training.evaluate.references.planar3r import planar3r_position
from training.run_log import LOG_FILE, LOSS_PLOT_FILE
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
    # The log holds each epoch once, the resumed session's lines after the first session's.
    assert [row["epoch"] for row in read_jsonl(run_dir / LOG_FILE)] == [0, 1, 2]


# Every training option beyond the paper's recipe, switched on at once; the tiny run has
# 5 batches an epoch.
ALL_OPTIONS = {
    "ema_decay": 0.9,
    "fresh_data": True,
    "time_sampling": "logit_normal",
    "architecture": "resmlp_adaln",
    "autocast_bf16": True,
}


@pytest.mark.parametrize(
    "options", [{}, {"fresh_data": True}, ALL_OPTIONS], ids=["paper", "fresh", "all"]
)
def test_a_run_stopped_mid_epoch_resumes_to_the_weights_of_an_uninterrupted_one(
    data: FlowData, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, options: dict[str, object]
) -> None:
    """With mid-epoch checkpoints after every batch, a run killed after batch 2 of epoch 1
    resumes from that batch and ends with the history and weights (the average's, with
    EMA) of a run that never wrote a checkpoint; fresh data is drawn again identically."""
    config = replace(TINY, checkpoint_minutes=0.0, **options)  # type: ignore[arg-type]
    uninterrupted = train(config, data)

    run_dir = tmp_path / "stopped"
    real_save = train_module.save_state

    def save_then_stop(path: Path, state: RunState) -> None:
        real_save(path, state)
        if (state.next_epoch, state.next_batch) == (1, 2):
            raise KeyboardInterrupt

    monkeypatch.setattr(train_module, "save_state", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        train(config, data, run_dir=run_dir)
    monkeypatch.undo()

    resumed = train(config, data, run_dir=run_dir, resume=True)
    assert resumed.history == uninterrupted.history
    assert resumed.best_epoch == uninterrupted.best_epoch
    assert weights_equal(resumed.model, uninterrupted.model)


def test_no_mid_epoch_checkpoint_before_checkpoint_minutes(
    data: FlowData, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With the default 5 minutes, a run of seconds writes last.pt once per epoch only."""
    saved: list[tuple[int, int]] = []
    real_save = train_module.save_state

    def counting(path: Path, state: RunState) -> None:
        saved.append((state.next_epoch, state.next_batch))
        real_save(path, state)

    monkeypatch.setattr(train_module, "save_state", counting)
    train(TINY, data, run_dir=tmp_path)
    assert saved == [(1, 0), (2, 0), (3, 0)]


def test_with_ema_the_kept_weights_are_the_hand_computed_average_of_the_steps(
    data: FlowData, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One epoch of 3 steps with ema_decay d: the returned (best) weights are
    d^3 theta_0 + (1 - d) (d^2 theta_1 + d theta_2 + theta_3) of the trained iterates, and
    the validation loss recorded is the average's."""
    decay = 0.5
    config = replace(TINY, epochs=1, batch_size=180, ema_decay=decay)  # 540 / 180 = 3 steps
    iterates: list[dict[str, torch.Tensor]] = []
    real_update = WeightAverage.update

    def recording(self: WeightAverage, model: torch.nn.Module) -> None:
        if not iterates:
            iterates.append({k: v.double().clone() for k, v in self.model.state_dict().items()})
        iterates.append({k: v.double().clone() for k, v in model.state_dict().items()})
        real_update(self, model)

    monkeypatch.setattr(WeightAverage, "update", recording)
    result = train(config, data)
    assert len(iterates) == 4
    weights = [decay**3, (1 - decay) * decay**2, (1 - decay) * decay, 1 - decay]
    for name, kept in result.model.state_dict().items():
        expected = sum(w * it[name] for w, it in zip(weights, iterates, strict=True))
        assert isinstance(expected, torch.Tensor)
        torch.testing.assert_close(kept.double(), expected, atol=1e-6, rtol=1e-5)
    assert not weights_equal_dicts(iterates[-1], result.model.state_dict())


def weights_equal_dicts(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return all(torch.equal(a[k].double(), b[k].double()) for k in a)


def test_fresh_data_gives_each_epoch_new_fk_consistent_pairs(
    data: FlowData, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With fresh_data, epoch 0 trains on the initial training split and epochs 1 and 2 on
    other configurations (none shared), each pair's condition the normalised closed-form
    FK of its configuration; the validation loss is measured on the same split."""
    seen: list[FlowPairs] = []
    real_epoch = train_module.train_one_epoch

    def recording(step: object, pairs: FlowPairs, *args: object, **kwargs: object) -> float:
        seen.append(pairs)
        return real_epoch(step, pairs, *args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(train_module, "train_one_epoch", recording)
    train(replace(TINY, fresh_data=True), data)
    labeller = data.labeller
    assert labeller is not None and len(seen) == 3
    initial = {tuple(row) for row in data.q_1.tolist()}
    epochs = [{tuple(row) for row in pairs.q_1.tolist()} for pairs in seen]
    assert epochs[0] <= initial and len(epochs[0]) == 540
    assert len(epochs[1]) == len(epochs[2]) == 540
    assert not epochs[1] & initial and not epochs[2] & initial and not epochs[1] & epochs[2]
    for pairs in seen:
        q = labeller.joint_normalisation.denormalise(pairs.q_1.double().numpy())
        expected = labeller.condition_normalisation.normalise(planar3r_position(q))
        np.testing.assert_allclose(pairs.condition.numpy(), expected, atol=1e-5)


def test_fresh_data_needs_a_labeller(data: FlowData) -> None:
    """FlowData made without a labeller cannot train with fresh_data; the error says why."""
    bare = FlowData(
        data.q_1, data.condition, data.joint_normalisation, data.condition_normalisation
    )
    with pytest.raises(ValueError, match="fresh_data needs FlowData with a labeller"):
        train(replace(TINY, fresh_data=True), bare)


def read_jsonl(path: Path) -> list[dict[str, float]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_the_run_log_has_a_line_per_epoch_and_the_loss_plot_is_a_png(
    data: FlowData, tmp_path: Path
) -> None:
    """log.jsonl: one line per epoch whose losses equal the history, optimiser steps
    (epoch + 1) x 5, the cosine schedule's rate lr0 (1 + cos(pi s / S)) / 2 after s of S
    steps, positive wall times (increasing) and throughput; loss.png decodes as a PNG."""
    result = train(TINY, data, run_dir=tmp_path)
    rows = read_jsonl(tmp_path / LOG_FILE)
    assert len(rows) == TINY.epochs
    for row, epoch in zip(rows, result.history, strict=True):
        assert row["epoch"] == epoch["epoch"]
        assert row["train_loss"] == epoch["train_loss"]
        assert row["validation_loss"] == epoch["validation_loss"]
        assert row["steps"] == (epoch["epoch"] + 1) * 5
        cosine = TINY.learning_rate * (1 + math.cos(math.pi * row["steps"] / 15)) / 2
        assert row["learning_rate"] == pytest.approx(cosine, abs=1e-12)
        assert row["samples_per_s"] > 0
    assert all(a["wall_time_s"] < b["wall_time_s"] for a, b in itertools.pairwise(rows))
    png = (tmp_path / LOSS_PLOT_FILE).read_bytes()
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
    image = matplotlib.image.imread(tmp_path / LOSS_PLOT_FILE)
    assert image.ndim == 3 and image.shape[0] > 100 and image.shape[1] > 100


def test_resume_refuses_a_run_written_with_other_settings(data: FlowData, tmp_path: Path) -> None:
    train(TINY, data, run_dir=tmp_path)
    other = TrainConfig(**{**TINY.as_dict(), "learning_rate": 5e-4})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"learning_rate \(0.001 there, 0.0005 now\)"):
        train(other, data, run_dir=tmp_path, resume=True)
    with pytest.raises(ValueError, match="nothing to resume"):
        train(TINY, data, run_dir=tmp_path / "empty", resume=True)
