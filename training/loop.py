"""The pieces every training loop here shares: the flow's (training/train.py) and the
reflow's (training/reflow.py).

- `atomic_write` / `atomic_torch_save`: a file written whole or not at all, so a run
  killed mid-write keeps its previous checkpoint, log or plot;
- `resume_payload`: the checkpoint a resumed run continues from, or a ValueError naming it;
- `Optimiser`: AdamW with a cosine schedule to 0 over the run's steps, one step of it,
  and its state for a checkpoint;
- `Best`: the best-so-far validation figure, where it was reached and those weights;
- `RunClock`: the run's wall time over every start of it (resumes included), and when a
  checkpoint is due.

Each loop supplies what differs: its data, its loss and batches, what its checkpoint
holds. None of these pieces draws from a random generator, so the loops draw exactly as
they would without them.
"""

from __future__ import annotations

import copy
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn


def atomic_write(path: Path, write: Callable[[Path], object]) -> None:
    """`write` to a temporary file beside `path`, then rename it to `path`: whole or not at all."""
    partial = path.with_name(path.name + ".partial")
    write(partial)
    os.replace(partial, path)


def atomic_torch_save(payload: dict[str, Any], path: Path) -> None:
    """torch.save `payload` to `path`, whole or not at all."""
    atomic_write(path, lambda partial: torch.save(payload, partial))


def resume_payload(path: Path | None) -> dict[str, Any]:
    """The checkpoint at `path` as torch saved it; ValueError when there is none."""
    if path is None or not path.is_file():
        raise ValueError(f"nothing to resume: {path} does not exist")
    payload: dict[str, Any] = torch.load(path, map_location="cpu", weights_only=False)
    return payload


@dataclass
class Optimiser:
    """AdamW and its cosine learning-rate schedule (to 0 after `total_steps` steps)."""

    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler

    @classmethod
    def cosine_adamw(
        cls, model: nn.Module, learning_rate: float, weight_decay: float, total_steps: int
    ) -> Optimiser:
        optimizer = torch.optim.AdamW(
            model.parameters(), lr=learning_rate, weight_decay=weight_decay
        )
        scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=total_steps)
        return cls(optimizer, scheduler)

    def step(self, loss: torch.Tensor) -> None:
        """One optimiser step down `loss`'s gradient, then the schedule's."""
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        self.optimizer.step()
        self.scheduler.step()

    def load(self, optimizer: dict[str, Any], scheduler: dict[str, Any]) -> None:
        """The state a checkpoint kept (`optimizer.state_dict()`, `scheduler.state_dict()`)."""
        self.optimizer.load_state_dict(optimizer)
        self.scheduler.load_state_dict(scheduler)

    @property
    def learning_rate(self) -> float:
        return float(self.scheduler.get_last_lr()[0])


@dataclass
class Best:
    """The lowest validation figure so far (`value`), the epoch or step it was reached at
    (`at`) and the weights then (`state`)."""

    value: float
    at: int
    state: dict[str, torch.Tensor]

    @classmethod
    def none_yet(cls, model: nn.Module) -> Best:
        """Before any validation: nothing beaten yet, `model`'s weights kept meanwhile."""
        return cls(math.inf, -1, copy.deepcopy(model.state_dict()))

    def offer(self, value: float, at: int, model: nn.Module) -> bool:
        """Keep `model`'s weights if `value` is lower than the best so far; whether it was."""
        if value < self.value:
            self.value, self.at, self.state = value, at, copy.deepcopy(model.state_dict())
            return True
        return False


@dataclass
class RunClock:
    """Wall time over every start of a run (`before_s`: the earlier starts'), and the
    checkpoint schedule: one due `every_minutes` after the last."""

    every_minutes: float
    before_s: float = 0.0
    started: float = field(default_factory=time.perf_counter)
    last_saved: float = field(init=False)

    def __post_init__(self) -> None:
        self.last_saved = self.started

    def wall_time_s(self) -> float:
        return self.before_s + time.perf_counter() - self.started

    def checkpoint_due(self) -> bool:
        return time.perf_counter() - self.last_saved >= 60 * self.every_minutes

    def saved(self) -> None:
        self.last_saved = time.perf_counter()
