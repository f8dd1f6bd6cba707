"""train and checkpoint: the loop keeps the best validation loss, and a run stopped after an
epoch resumes from last.pt to exactly the weights of a run that never stopped."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from service.manifest import REPO_MODELS_DIR
from training import train as train_module
from training.checkpoint import LAST_FILE, load_best, save_best
from training.config import TrainConfig, preset
from training.data import FlowData, build_flow_data
from training.kinematics import ForwardKinematics, joint_spec, load_chain
from training.robots import robot_spec
from training.train import build_model, train

TINY = TrainConfig(
    **{
        **preset("planar3r", "position").as_dict(),
        "samples": 600,
        "epochs": 3,
        "batch_size": 128,
        "hidden_width": 16,
        "hidden_layers": 2,
    }  # type: ignore[arg-type]
)


@pytest.fixture(scope="module")
def data() -> FlowData:
    robot = robot_spec("planar3r")
    chain = load_chain(REPO_MODELS_DIR / robot.urdf, robot.end_effector_link)
    return build_flow_data(
        ForwardKinematics(chain), joint_spec(chain), robot.task("position"), TINY.samples, 1
    )


def _weights_equal(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    pairs = zip(a.state_dict().values(), b.state_dict().values(), strict=True)
    return all(torch.equal(x, y) for x, y in pairs)


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
    assert _weights_equal(resumed.model, uninterrupted.model)


def test_resume_refuses_a_run_written_with_other_settings(data: FlowData, tmp_path: Path) -> None:
    train(TINY, data, run_dir=tmp_path)
    other = TrainConfig(**{**TINY.as_dict(), "learning_rate": 5e-4})  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"learning_rate \(0.001 there, 0.0005 now\)"):
        train(other, data, run_dir=tmp_path, resume=True)
    with pytest.raises(ValueError, match="nothing to resume"):
        train(TINY, data, run_dir=tmp_path / "empty", resume=True)


def test_best_checkpoint_round_trips_weights_and_provenance(data: FlowData, tmp_path: Path) -> None:
    result = train(TINY, data)
    save_best(tmp_path / "best.pt", result, TINY, command="smm-train --robot planar3r")
    best = load_best(tmp_path / "best.pt")
    assert best.config == TINY and best.command == "smm-train --robot planar3r"
    restored = best.result(build_model(best.config, data))
    assert restored.best_validation_loss == result.best_validation_loss
    assert restored.best_epoch == result.best_epoch
    assert _weights_equal(restored.model, result.model)
