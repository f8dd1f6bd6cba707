"""What a training run keeps on disk (runs/<model-id>/, never in git), and the trained result.

- `best.pt`: the best-validation weights with their provenance; `smm-train
  --from-checkpoint` re-exports it without training.
- `last.pt`: everything needed to go on after the last finished epoch (weights, optimiser,
  schedule, random generator, weight average, best so far, history, wall time), written
  also mid-epoch (every `checkpoint_minutes`) with where the epoch stood; `smm-train
  --resume` continues from it and ends with the same weights as a run never stopped.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import torch

from training.config import TrainConfig
from training.loop import atomic_torch_save, resume_payload
from training.model import VelocityField

BEST_FILE = "best.pt"
LAST_FILE = "last.pt"
HISTORY_FILE = "history.json"
# Settings a resumed run may change: where and how fast it runs, and the measurement after.
CHANGEABLE_ON_RESUME = frozenset(
    {
        "device",
        "threads",
        "eval_targets",
        "eval_samples_per_target",
        "eval_seed",
        "sweep_targets",
        "sweep_seed",
        "checkpoint_minutes",
        "reflow_steps",
        "reflow_pairs",
        "judge_targets",
    }
)


@dataclass(frozen=True)
class TrainResult:
    """A trained flow and the record of how it was trained."""

    model: VelocityField  # best-validation weights (the weight average's with ema_decay)
    best_validation_loss: float
    best_epoch: int
    history: list[dict[str, float]]  # per epoch: epoch, train_loss, validation_loss
    wall_time_s: float


@dataclass(frozen=True)
class BestCheckpoint:
    """best.pt: the weights to export, the config that made them, and the command."""

    config: TrainConfig
    state_dict: dict[str, torch.Tensor]
    best_validation_loss: float
    best_epoch: int
    wall_time_s: float
    command: str
    # The commit the run started from (training.checkout.git_commit); None in a best.pt
    # written before runs stored it.
    git_commit: str | None = None
    # The processor that trained it (training.machine.Machine.processor); None likewise.
    processor: dict[str, object] | None = None

    def result(self, model: VelocityField) -> TrainResult:
        """`model` (built from `config`) with these weights, as a TrainResult."""
        model.load_state_dict(self.state_dict)
        return TrainResult(
            model=model.eval(),
            best_validation_loss=self.best_validation_loss,
            best_epoch=self.best_epoch,
            history=[],
            wall_time_s=self.wall_time_s,
        )


def save_best(
    path: Path,
    result: TrainResult,
    config: TrainConfig,
    command: str,
    git_commit: str,
    processor: dict[str, object],
) -> None:
    atomic_torch_save(
        {
            "git_commit": git_commit,
            "processor": processor,
            "state_dict": result.model.state_dict(),
            "best_validation_loss": result.best_validation_loss,
            "best_epoch": result.best_epoch,
            "wall_time_s": result.wall_time_s,
            "config": config.as_dict(),
            "command": command,
        },
        path,
    )


def load_best(path: Path) -> BestCheckpoint:
    checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    return BestCheckpoint(
        config=TrainConfig(**checkpoint["config"]),
        state_dict=checkpoint["state_dict"],
        best_validation_loss=checkpoint["best_validation_loss"],
        best_epoch=checkpoint["best_epoch"],
        wall_time_s=checkpoint["wall_time_s"],
        command=checkpoint["command"],
        git_commit=checkpoint.get("git_commit"),
        processor=checkpoint.get("processor"),
    )


@dataclass
class RunState:
    """last.pt: a run after `next_epoch` finished epochs and `next_batch` batches of the
    next one, enough to continue it exactly. Fields with defaults came later: a last.pt
    written before them loads as a run without them."""

    config: TrainConfig
    next_epoch: int
    model: dict[str, torch.Tensor]
    optimizer: dict[str, Any]
    scheduler: dict[str, Any]
    generator: torch.Tensor  # torch.Generator.get_state()
    best_validation_loss: float
    best_epoch: int
    best_model: dict[str, torch.Tensor]
    history: list[dict[str, float]]
    wall_time_s: float  # training time so far, over every start (resumes included)
    ema_model: dict[str, torch.Tensor] | None = None  # the weight average, when ema_decay > 0
    # Mid-epoch: the generator state the epoch's shuffle was drawn from, the batches done
    # and the sum of their losses (next_batch 0: at an epoch boundary).
    epoch_start_generator: torch.Tensor | None = None
    next_batch: int = 0
    epoch_loss_sum: float = 0.0
    # A distributed run (config.world_size > 1): `generator` is then the shuffle generator
    # every process shares, and these hold each process's own, by rank: the state of its
    # noise-and-time generator and its sum of the current epoch's batch losses.
    rank_generators: list[torch.Tensor] | None = None
    rank_epoch_loss_sums: list[float] | None = None


def save_state(path: Path, state: RunState) -> None:
    payload = {f.name: getattr(state, f.name) for f in fields(RunState)}
    payload["config"] = state.config.as_dict()
    atomic_torch_save(payload, path)


def load_state(path: Path | None, config: TrainConfig) -> RunState:
    """The run state in `path`; ValueError when there is none, or naming the fields when it
    was made by another config."""
    payload = resume_payload(path)
    saved = TrainConfig(**payload["config"])
    if saved.world_size != config.world_size:
        raise ValueError(
            f"{path} was written by a run of {saved.world_size} training process(es), this "
            f"run has {config.world_size}: a run continues only with as many as it started "
            "with (each process's data shard and noise generator, and the length of the "
            f"learning-rate schedule, follow from that number); resume it with {saved.world_size} "
            "(torchrun's --nproc-per-node x --nnodes; plain smm-train is 1), or start afresh "
            "without --resume"
        )
    differing = [
        f"{f.name} ({getattr(saved, f.name)!r} there, {getattr(config, f.name)!r} now)"
        for f in fields(TrainConfig)
        if f.name not in CHANGEABLE_ON_RESUME and getattr(saved, f.name) != getattr(config, f.name)
    ]
    if differing:
        raise ValueError(
            f"{path} was written by a run with other settings: {', '.join(differing)}; "
            "resume with the same flags, or start afresh without --resume"
        )
    payload["config"] = config
    return RunState(**payload)
