"""The training loop: conditional flow matching over (q, FK(q)) pairs, best validation kept.

`train()` runs the epochs; with a run directory it writes, after every epoch, `log.jsonl`
and `loss.png` (run_log.py) and `last.pt` (checkpoint.py), and `last.pt` also mid-epoch at
most every `checkpoint_minutes`, so a run that is stopped anywhere continues with
`resume=True` to the same weights. The command line is `training/cli.py`.

Given `Processes` of a distributed run (training/distributed.py), the processes train one
model together: each draws the shared shuffle of every epoch and trains on its shard with
its own noise and times (seed + rank), DistributedDataParallel averaging the gradients; the
validation loss is the mean over the whole validation split (each process measures a part);
only rank 0 writes the run directory. One process (the default) trains exactly as before.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import torch
from torch import nn
from tqdm import tqdm

from training.checkpoint import LAST_FILE, RunState, TrainResult, load_state, save_state
from training.config import TrainConfig
from training.data import FlowData, FlowPairs, fresh_seed
from training.distributed import SINGLE, Processes, wrap
from training.ema import WeightAverage
from training.flow import TimeSampling, cfm_loss
from training.model import VelocityField
from training.run_log import LOG_FILE, LOSS_PLOT_FILE, plot_losses, read_log, write_log


def build_model(config: TrainConfig, data: FlowData) -> VelocityField:
    """The velocity field of `config`'s architecture for `data`'s joint and condition sizes."""
    return VelocityField(
        joint_dim=data.q_1.shape[1],
        condition_dim=data.condition.shape[1],
        hidden_width=config.hidden_width,
        hidden_layers=config.hidden_layers,
        time_embedding_dim=config.time_embedding_dim,
        architecture=config.architecture,
    )


def split(
    data: FlowData, fraction: float, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Shuffled indices: (train (N_train,), validation (N_val,))."""
    order = torch.randperm(data.q_1.shape[0], generator=generator)
    num_val = max(1, round(fraction * len(order)))
    return order[num_val:], order[:num_val]


@dataclass
class Optimisation:
    """What a training step updates and draws from."""

    model: VelocityField
    network: nn.Module  # what the forward pass runs through: `model`, or its DDP wrapper
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    ema: WeightAverage | None  # updated after every step when on
    generator: torch.Generator  # noise and times (this process's own, when distributed)
    times: TimeSampling
    batch_size: int
    autocast_bf16: bool  # the forward pass under bf16 autocast; the loss in float32


@dataclass
class EpochCursor:
    """Where an epoch stands: the generator state its shuffle was drawn from, the batches
    done and the sum of their losses."""

    start_generator: torch.Tensor
    next_batch: int = 0
    loss_sum: float = 0.0


def train_one_epoch(
    step: Optimisation,
    pairs: FlowPairs,
    order: torch.Tensor,
    cursor: EpochCursor,
    progress: tqdm,
    after_batch: Callable[[EpochCursor], None] | None = None,
) -> float:
    """The batches of `order` (N,) from `cursor.next_batch` on; returns the epoch's mean loss.

    `after_batch` sees the cursor after every batch but the epoch's last.
    """
    network = step.network
    network.train()
    device = pairs.q_1.device
    batches = math.ceil(len(order) / step.batch_size)
    for batch in range(cursor.next_batch, batches):
        index = order[batch * step.batch_size : (batch + 1) * step.batch_size]
        q_0 = torch.randn(len(index), pairs.q_1.shape[1], generator=step.generator).to(device)
        t = step.times.sample(len(index), step.generator).to(device)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=step.autocast_bf16):
            loss = cfm_loss(network, pairs.q_1[index], pairs.condition[index], q_0, t)
        step.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        step.optimizer.step()
        step.scheduler.step()
        if step.ema is not None:
            step.ema.update(step.model)
        cursor.loss_sum += loss.item()
        cursor.next_batch = batch + 1
        progress.update(1)
        if after_batch is not None and cursor.next_batch < batches:
            after_batch(cursor)
    return cursor.loss_sum / batches


@torch.no_grad()
def validation_loss(
    model: nn.Module,
    q_1: torch.Tensor,
    condition: torch.Tensor,
    q_0: torch.Tensor,
    t: torch.Tensor,
    batch_size: int = 65_536,
) -> float:
    """Validation CFM loss with fixed noise and uniform times, in float32, so epochs (and
    runs with other time samplings or autocast) compare like for like."""
    model.eval()
    total = 0.0
    for start in range(0, q_1.shape[0], batch_size):
        s = slice(start, start + batch_size)
        total += float(cfm_loss(model, q_1[s], condition[s], q_0[s], t[s])) * len(q_1[s])
    return total / q_1.shape[0]


def train(
    config: TrainConfig,
    data: FlowData,
    run_dir: Path | None = None,
    resume: bool = False,
    processes: Processes = SINGLE,
) -> TrainResult:
    """Train `config.epochs` epochs on `data`; return the best-validation weights.

    With `run_dir`, the state goes to `run_dir/last.pt` after each epoch (and mid-epoch
    every `config.checkpoint_minutes`), with log.jsonl and loss.png beside it; with
    `resume`, training continues from there (ValueError if it was written with other
    settings). With `config.fresh_data`, epochs after the first train on new
    configurations from `data.labeller`; the validation split stays `data`'s. With
    `processes` of a distributed run (in a process group, `config.world_size` processes),
    every process calls this with the same arguments and gets the same result.
    """
    times = TimeSampling(config.time_sampling, config.time_logit_mean, config.time_logit_std)
    labeller = data.labeller
    if config.fresh_data and labeller is None:
        raise ValueError("fresh_data needs FlowData with a labeller (build_flow_data makes one)")
    if config.world_size != processes.world_size:
        raise ValueError(
            f"config.world_size is {config.world_size} but {processes.world_size} processes train"
        )
    torch.manual_seed(config.seed)
    # Split, validation noise and each epoch's shuffle: the same on every process.
    generator = torch.Generator().manual_seed(config.seed)
    # Training noise and times: one process draws them from `generator` too; several each
    # from their own, so that their batches differ in noise as well as in samples.
    noise = generator
    if processes.distributed:
        noise = torch.Generator().manual_seed(config.seed + processes.rank)
    device = processes.device(config.device)
    train_index, val_index = split(data, config.validation_fraction, generator)
    train_pairs = FlowPairs(
        data.q_1[train_index].to(device), data.condition[train_index].to(device)
    )
    q_val = data.q_1[val_index].to(device)
    c_val = data.condition[val_index].to(device)
    q_0_val = torch.randn(q_val.shape, generator=generator).to(device)
    t_val = torch.rand(q_val.shape[0], 1, generator=generator).to(device)
    val_part = processes.part(len(val_index))  # this process's rows of the split
    val_rows = len(q_val[val_part])
    shard_size = len(processes.shard(train_index))
    if processes.distributed:
        print(
            f"process {processes.rank} of {processes.world_size}: {shard_size} of "
            f"{len(train_index)} training samples per epoch, {val_rows} of {len(val_index)} "
            "validation samples",
            flush=True,
        )

    model = build_model(config, data).to(device)
    optimizer = torch.optim.AdamW(
        model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    steps_per_epoch = math.ceil(shard_size / config.batch_size)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
        optimizer, T_max=config.epochs * steps_per_epoch
    )
    step = Optimisation(
        model=model,
        network=wrap(model, processes),
        optimizer=optimizer,
        scheduler=scheduler,
        ema=None if config.ema_decay == 0 else WeightAverage(model, config.ema_decay),
        generator=noise,
        times=times,
        batch_size=config.batch_size,
        autocast_bf16=config.autocast_bf16,
    )
    evaluated = model if step.ema is None else step.ema.model  # validated, kept, exported
    first_epoch, elapsed_s, resumed_cursor = 0, 0.0, None
    best_loss, best_epoch, best_state = math.inf, -1, copy.deepcopy(evaluated.state_dict())
    history: list[dict[str, float]] = []
    log_rows: list[dict[str, float]] = []
    last_path = None if run_dir is None else run_dir / LAST_FILE
    if run_dir is not None and processes.is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
    if resume:
        if last_path is None or not last_path.is_file():
            raise ValueError(f"nothing to resume: {last_path} does not exist")
        state = load_state(last_path, config)
        model.load_state_dict(state.model)
        optimizer.load_state_dict(state.optimizer)
        scheduler.load_state_dict(state.scheduler)
        generator.set_state(state.generator)
        loss_sum = state.epoch_loss_sum
        if processes.distributed:
            if state.rank_generators is None or state.rank_epoch_loss_sums is None:
                raise ValueError(f"{last_path} lacks the processes' generators")
            noise.set_state(state.rank_generators[processes.rank])
            loss_sum = state.rank_epoch_loss_sums[processes.rank]
        if step.ema is not None and state.ema_model is not None:
            step.ema.model.load_state_dict(state.ema_model)
        first_epoch, elapsed_s = state.next_epoch, state.wall_time_s
        best_loss, best_epoch, best_state = (
            state.best_validation_loss,
            state.best_epoch,
            state.best_model,
        )
        history = state.history
        if state.next_batch and state.epoch_start_generator is not None:
            resumed_cursor = EpochCursor(state.epoch_start_generator, state.next_batch, loss_sum)
        if run_dir is not None:
            log_rows = [r for r in read_log(run_dir / LOG_FILE) if r["epoch"] < first_epoch]
    session_start = time.perf_counter()
    last_saved = session_start

    def wall_time_s() -> float:
        return elapsed_s + time.perf_counter() - session_start

    def save(next_epoch: int, cursor: EpochCursor | None) -> None:
        nonlocal last_saved
        if last_path is None:
            return
        rank_generators, rank_loss_sums = None, None
        if processes.distributed:  # every process's generator and loss sum, to rank 0
            gathered = processes.gather(
                (noise.get_state(), 0.0 if cursor is None else cursor.loss_sum)
            )
            rank_generators = [rank_state for rank_state, _ in gathered]
            rank_loss_sums = [rank_sum for _, rank_sum in gathered]
        if not processes.is_main:
            last_saved = time.perf_counter()
            return
        save_state(
            last_path,
            RunState(
                config=config,
                next_epoch=next_epoch,
                model=model.state_dict(),
                optimizer=optimizer.state_dict(),
                scheduler=scheduler.state_dict(),
                generator=generator.get_state(),
                best_validation_loss=best_loss,
                best_epoch=best_epoch,
                best_model=best_state,
                history=history,
                wall_time_s=wall_time_s(),
                ema_model=None if step.ema is None else step.ema.model.state_dict(),
                epoch_start_generator=None if cursor is None else cursor.start_generator,
                next_batch=0 if cursor is None else cursor.next_batch,
                epoch_loss_sum=0.0 if cursor is None else cursor.loss_sum,
                rank_generators=rank_generators,
                rank_epoch_loss_sums=rank_loss_sums,
            ),
        )
        last_saved = time.perf_counter()

    def save_if_due(epoch: int, cursor: EpochCursor) -> None:
        if last_path is None:
            return
        # Rank 0's clock decides: saving gathers from every process.
        if processes.agree(time.perf_counter() - last_saved >= 60 * config.checkpoint_minutes):
            save(epoch, cursor)

    batches_done = first_epoch * steps_per_epoch + (
        resumed_cursor.next_batch if resumed_cursor else 0
    )
    with tqdm(
        total=config.epochs * steps_per_epoch,
        initial=batches_done,
        unit="batch",
        mininterval=2.0,
        smoothing=0.0,  # ETA from this process's mean rate, pauses (validation, labels) included
        disable=not processes.is_main,
    ) as progress:
        for epoch in range(first_epoch, config.epochs):
            labelling_started = time.perf_counter()
            pairs = train_pairs
            if config.fresh_data and epoch > 0 and labeller is not None:
                fresh = labeller(len(train_index), fresh_seed(config.seed, epoch))
                pairs = FlowPairs(fresh.q_1.to(device), fresh.condition.to(device))
            labelling_s = time.perf_counter() - labelling_started
            if resumed_cursor is None:
                cursor = EpochCursor(generator.get_state())
                order = torch.randperm(len(train_index), generator=generator).to(device)
            else:  # the shuffle drawn before the stop, then the generator where it stopped
                cursor, resumed_cursor = resumed_cursor, None
                now = generator.get_state()
                generator.set_state(cursor.start_generator)
                order = torch.randperm(len(train_index), generator=generator).to(device)
                generator.set_state(now)
            order = processes.shard(order)
            first_batch, training_started = cursor.next_batch, time.perf_counter()
            train_loss = train_one_epoch(
                step, pairs, order, cursor, progress, after_batch=partial(save_if_due, epoch)
            )
            train_loss = processes.mean(train_loss)  # every process ran as many batches
            training_s = time.perf_counter() - training_started
            val_loss = processes.weighted_mean(
                validation_loss(
                    evaluated, q_val[val_part], c_val[val_part], q_0_val[val_part], t_val[val_part]
                )
                if val_rows
                else 0.0,
                val_rows,
            )
            history.append({"epoch": epoch, "train_loss": train_loss, "validation_loss": val_loss})
            if val_loss < best_loss:
                best_loss, best_epoch = val_loss, epoch
                best_state = copy.deepcopy(evaluated.state_dict())
            progress.set_postfix(
                epoch=epoch, train=f"{train_loss:.4f}", validation=f"{val_loss:.4f}"
            )
            if run_dir is not None and processes.is_main:
                samples = (len(order) - first_batch * config.batch_size) * processes.world_size
                log_rows.append(
                    {
                        "epoch": epoch,
                        "steps": (epoch + 1) * steps_per_epoch,
                        "train_loss": train_loss,
                        "validation_loss": val_loss,
                        "learning_rate": float(scheduler.get_last_lr()[0]),
                        "wall_time_s": wall_time_s(),
                        "samples_per_s": samples / training_s,
                        "labelling_s": labelling_s,
                    }
                )
                write_log(run_dir / LOG_FILE, log_rows)
                plot_losses(run_dir / LOSS_PLOT_FILE, history)
            save(epoch + 1, None)
    model.load_state_dict(best_state)
    return TrainResult(
        model=model.cpu().eval(),
        best_validation_loss=best_loss,
        best_epoch=best_epoch,
        history=history,
        wall_time_s=wall_time_s(),
    )
