"""The training loop: conditional flow matching over (q, FK(q)) pairs, best validation kept.

`train()` runs the epochs; with a run directory it writes `last.pt` after every epoch
(checkpoint.py), so a run that is stopped continues with `resume=True` to the same
weights. The command line is `training/cli.py`.
"""

from __future__ import annotations

import copy
import math
import time
from pathlib import Path

import torch
from tqdm import tqdm

from training.checkpoint import LAST_FILE, RunState, TrainResult, load_state, save_state
from training.config import TrainConfig
from training.data import FlowData
from training.flow import cfm_loss
from training.model import VelocityField


def build_model(config: TrainConfig, data: FlowData) -> VelocityField:
    """The velocity field of `config`'s architecture for `data`'s joint and condition sizes."""
    return VelocityField(
        joint_dim=data.q_1.shape[1],
        condition_dim=data.condition.shape[1],
        hidden_width=config.hidden_width,
        hidden_layers=config.hidden_layers,
        time_embedding_dim=config.time_embedding_dim,
    )


def split(
    data: FlowData, fraction: float, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Shuffled indices: (train (N_train,), validation (N_val,))."""
    order = torch.randperm(data.q_1.shape[0], generator=generator)
    num_val = max(1, round(fraction * len(order)))
    return order[num_val:], order[:num_val]


def train_one_epoch(
    model: VelocityField,
    q_1: torch.Tensor,
    condition: torch.Tensor,
    optimizer: torch.optim.Optimizer,
    scheduler: torch.optim.lr_scheduler.LRScheduler,
    batch_size: int,
    generator: torch.Generator,
    progress: tqdm,
) -> float:
    """One pass over (q_1, condition) in shuffled batches; returns the mean training loss."""
    model.train()
    device = q_1.device
    order = torch.randperm(q_1.shape[0], generator=generator).to(device)
    total, batches = 0.0, 0
    for start in range(0, len(order), batch_size):
        index = order[start : start + batch_size]
        q_0 = torch.randn(len(index), q_1.shape[1], generator=generator).to(device)
        t = torch.rand(len(index), 1, generator=generator).to(device)
        loss = cfm_loss(model, q_1[index], condition[index], q_0, t)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        scheduler.step()
        total += loss.item()
        batches += 1
        progress.update(1)
    return total / batches


@torch.no_grad()
def validation_loss(
    model: VelocityField,
    q_1: torch.Tensor,
    condition: torch.Tensor,
    q_0: torch.Tensor,
    t: torch.Tensor,
    batch_size: int = 65_536,
) -> float:
    """Validation CFM loss with fixed noise and times, so epochs compare like for like."""
    model.eval()
    total = 0.0
    for start in range(0, q_1.shape[0], batch_size):
        s = slice(start, start + batch_size)
        total += float(cfm_loss(model, q_1[s], condition[s], q_0[s], t[s])) * len(q_1[s])
    return total / q_1.shape[0]


def train(
    config: TrainConfig, data: FlowData, run_dir: Path | None = None, resume: bool = False
) -> TrainResult:
    """Train `config.epochs` epochs on `data`; return the best-validation weights.

    With `run_dir`, the state after each epoch goes to `run_dir/last.pt`; with `resume`,
    training continues from there (ValueError if it was written with other settings).
    """
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    device = torch.device(config.device)
    train_index, val_index = split(data, config.validation_fraction, generator)
    q_train = data.q_1[train_index].to(device)
    c_train = data.condition[train_index].to(device)
    q_val = data.q_1[val_index].to(device)
    c_val = data.condition[val_index].to(device)
    q_0_val = torch.randn(q_val.shape, generator=generator).to(device)
    t_val = torch.rand(q_val.shape[0], 1, generator=generator).to(device)

    model = build_model(config, data).to(device)
    optimizer = torch.optim.AdamW(
        model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    steps_per_epoch = math.ceil(q_train.shape[0] / config.batch_size)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
        optimizer, T_max=config.epochs * steps_per_epoch
    )
    first_epoch, elapsed_s = 0, 0.0
    best_loss, best_epoch, best_state = math.inf, -1, copy.deepcopy(model.state_dict())
    history: list[dict[str, float]] = []
    last_path = None if run_dir is None else run_dir / LAST_FILE
    if run_dir is not None:
        run_dir.mkdir(parents=True, exist_ok=True)
    if resume:
        if last_path is None or not last_path.is_file():
            raise ValueError(f"nothing to resume: {last_path} does not exist")
        state = load_state(last_path, config)
        model.load_state_dict(state.model)
        optimizer.load_state_dict(state.optimizer)
        scheduler.load_state_dict(state.scheduler)
        generator.set_state(state.generator)
        first_epoch, elapsed_s = state.next_epoch, state.wall_time_s
        best_loss, best_epoch, best_state = (
            state.best_validation_loss,
            state.best_epoch,
            state.best_model,
        )
        history = state.history

    session_start = time.perf_counter()
    with tqdm(
        total=config.epochs * steps_per_epoch,
        initial=first_epoch * steps_per_epoch,
        unit="batch",
        mininterval=2.0,
    ) as progress:
        for epoch in range(first_epoch, config.epochs):
            train_loss = train_one_epoch(
                model=model,
                q_1=q_train,
                condition=c_train,
                optimizer=optimizer,
                scheduler=scheduler,
                batch_size=config.batch_size,
                generator=generator,
                progress=progress,
            )
            val_loss = validation_loss(model, q_val, c_val, q_0_val, t_val)
            history.append({"epoch": epoch, "train_loss": train_loss, "validation_loss": val_loss})
            if val_loss < best_loss:
                best_loss, best_epoch = val_loss, epoch
                best_state = copy.deepcopy(model.state_dict())
            progress.set_postfix(
                epoch=epoch, train=f"{train_loss:.4f}", validation=f"{val_loss:.4f}"
            )
            if last_path is not None:
                save_state(
                    last_path,
                    RunState(
                        config=config,
                        next_epoch=epoch + 1,
                        model=model.state_dict(),
                        optimizer=optimizer.state_dict(),
                        scheduler=scheduler.state_dict(),
                        generator=generator.get_state(),
                        best_validation_loss=best_loss,
                        best_epoch=best_epoch,
                        best_model=best_state,
                        history=history,
                        wall_time_s=elapsed_s + time.perf_counter() - session_start,
                    ),
                )
    model.load_state_dict(best_state)
    return TrainResult(
        model=model.cpu().eval(),
        best_validation_loss=best_loss,
        best_epoch=best_epoch,
        history=history,
        wall_time_s=elapsed_s + time.perf_counter() - session_start,
    )
