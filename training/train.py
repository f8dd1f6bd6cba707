"""The training loop: conditional flow matching over (q, FK(q)) pairs, best validation kept.

`train()` runs the epochs (with the pieces it shares with the reflow, training/loop.py);
with a run directory it writes, after every epoch, `log.jsonl` and `loss.png` (run_log.py)
and `last.pt` (checkpoint.py), and `last.pt` also mid-epoch at most every
`checkpoint_minutes`, so a run that is stopped anywhere continues with `resume=True` to the
same weights. The command line is `smm-train train` (training/train_command.py).

Given `Processes` of a distributed run (training/distributed.py), the processes train one
model together: each draws the shared shuffle of every epoch and trains on its shard with
its own noise and times (seed + rank), DistributedDataParallel averaging the gradients; the
validation loss is the mean over the whole validation split (each process measures a part);
only rank 0 writes the run directory. One process (the default) trains exactly as before.
"""

from __future__ import annotations

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
from training.loop import Best, Optimiser, RunClock
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
    optimiser: Optimiser
    ema: WeightAverage | None  # updated after every step when on
    generator: torch.Generator  # noise and times (this process's own, when distributed)
    times: TimeSampling
    batch_size: int
    autocast_bf16: bool  # the forward pass under bf16 autocast; the loss in float32


@dataclass
class EpochCursor:
    """Where an epoch stands: the generator state its shuffle was drawn from, the batches
    done and the sum of their losses.

    During the epoch the sum runs on the training device (`running`, float64, so that it
    adds exactly what `loss.item()` would have): reading a loss back every batch would
    stall a GPU at each step. `settle()` brings it back before it is read.
    """

    start_generator: torch.Tensor
    next_batch: int = 0
    loss_sum: float = 0.0
    running: torch.Tensor | None = None  # () float64 on the device: loss_sum and the batches since

    def add(self, loss: torch.Tensor) -> None:
        if self.running is None:
            self.running = torch.tensor(self.loss_sum, dtype=torch.float64, device=loss.device)
        self.running += loss.detach()

    def settle(self) -> float:
        """The sum of the losses so far, as a number (one device read)."""
        if self.running is not None:
            self.loss_sum = float(self.running)
            self.running = None
        return self.loss_sum


def to_device(tensor: torch.Tensor, device: torch.device) -> torch.Tensor:
    """A CPU tensor on `device`; to a GPU through pinned memory without waiting for it, so
    that drawing the noise on the CPU (the same draws on any device) stalls no step."""
    if device.type == "cpu":
        return tensor
    return tensor.pin_memory().to(device, non_blocking=True)


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
        noise = torch.randn(len(index), pairs.q_1.shape[1], generator=step.generator)
        q_0 = to_device(noise, device)
        t = to_device(step.times.sample(len(index), step.generator), device)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=step.autocast_bf16):
            loss = cfm_loss(network, pairs.q_1[index], pairs.condition[index], q_0, t)
        step.optimiser.step(loss)
        if step.ema is not None:
            step.ema.update(step.model)
        cursor.add(loss)
        cursor.next_batch = batch + 1
        progress.update(1)
        if after_batch is not None and cursor.next_batch < batches:
            after_batch(cursor)
    return cursor.settle() / batches


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


@dataclass(frozen=True)
class Split:
    """The training pairs on the device, and this process's part of the validation split
    with its fixed noise and times."""

    train_index: torch.Tensor  # (N_train,) rows of the data
    train_pairs: FlowPairs
    validation: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]  # q_1, x, q_0, t
    validation_rows: int  # this process's


def split_data(
    config: TrainConfig,
    data: FlowData,
    generator: torch.Generator,
    processes: Processes,
    device: torch.device,
) -> Split:
    """The split, then the validation noise and times, drawn from `generator` in that order."""
    train_index, val_index = split(data, config.validation_fraction, generator)
    train_pairs = FlowPairs(
        data.q_1[train_index].to(device), data.condition[train_index].to(device)
    )
    q_val = data.q_1[val_index].to(device)
    c_val = data.condition[val_index].to(device)
    q_0_val = torch.randn(q_val.shape, generator=generator).to(device)
    t_val = torch.rand(q_val.shape[0], 1, generator=generator).to(device)
    val_part = processes.part(len(val_index))  # this process's rows of the split
    validation = (q_val[val_part], c_val[val_part], q_0_val[val_part], t_val[val_part])
    val_rows = len(validation[0])
    if processes.distributed:
        print(
            f"process {processes.rank} of {processes.world_size}: "
            f"{len(processes.shard(train_index))} of {len(train_index)} training samples per "
            f"epoch, {val_rows} of {len(val_index)} validation samples",
            flush=True,
        )
    return Split(train_index, train_pairs, validation, val_rows)


@dataclass
class Run:
    """A run's progress besides the optimisation's own state: the epoch it goes on from,
    the best so far, the history and log lines, its clock, and where a stopped epoch stood."""

    first_epoch: int
    best: Best
    history: list[dict[str, float]]
    log_rows: list[dict[str, float]]
    clock: RunClock
    resumed_cursor: EpochCursor | None = None


def start_run(
    config: TrainConfig,
    step: Optimisation,
    evaluated: nn.Module,
    shuffle: torch.Generator,
    run_dir: Path | None,
    resume: bool,
    processes: Processes,
) -> Run:
    """A fresh run, or (`resume`) the one run_dir/last.pt holds, its state loaded into
    `step`, `evaluated`'s average and the `shuffle` generator."""
    if run_dir is not None and processes.is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
    if not resume:
        return Run(0, Best.none_yet(evaluated), [], [], RunClock(config.checkpoint_minutes))
    last_path = None if run_dir is None else run_dir / LAST_FILE
    state = load_state(last_path, config)
    step.model.load_state_dict(state.model)
    step.optimiser.load(state.optimizer, state.scheduler)
    shuffle.set_state(state.generator)
    loss_sum = state.epoch_loss_sum
    if processes.distributed:
        if state.rank_generators is None or state.rank_epoch_loss_sums is None:
            raise ValueError(f"{last_path} lacks the processes' generators")
        step.generator.set_state(state.rank_generators[processes.rank])
        loss_sum = state.rank_epoch_loss_sums[processes.rank]
    if step.ema is not None and state.ema_model is not None:
        step.ema.model.load_state_dict(state.ema_model)
    resumed_cursor = None
    if state.next_batch and state.epoch_start_generator is not None:
        resumed_cursor = EpochCursor(state.epoch_start_generator, state.next_batch, loss_sum)
    log_rows = []
    if run_dir is not None:
        log_rows = [r for r in read_log(run_dir / LOG_FILE) if r["epoch"] < state.next_epoch]
    return Run(
        first_epoch=state.next_epoch,
        best=Best(state.best_validation_loss, state.best_epoch, state.best_model),
        history=state.history,
        log_rows=log_rows,
        clock=RunClock(config.checkpoint_minutes, before_s=state.wall_time_s),
        resumed_cursor=resumed_cursor,
    )


@dataclass
class Checkpointer:
    """Writes run_dir/last.pt (rank 0, every process having handed it its own generator
    and loss sum) at each epoch's end and, mid-epoch, when the run's clock says it is due."""

    config: TrainConfig
    step: Optimisation
    shuffle: torch.Generator  # the epochs' shuffle (and, with one process, the noise)
    run: Run
    last_path: Path | None
    processes: Processes

    def save(self, next_epoch: int, cursor: EpochCursor | None) -> None:
        if self.last_path is None:
            return
        if cursor is not None:
            cursor.settle()
        rank_generators, rank_loss_sums = None, None
        if self.processes.distributed:  # every process's generator and loss sum, to rank 0
            gathered = self.processes.gather(
                (self.step.generator.get_state(), 0.0 if cursor is None else cursor.loss_sum)
            )
            rank_generators = [rank_state for rank_state, _ in gathered]
            rank_loss_sums = [rank_sum for _, rank_sum in gathered]
        if self.processes.is_main:
            step, best = self.step, self.run.best
            save_state(
                self.last_path,
                RunState(
                    config=self.config,
                    next_epoch=next_epoch,
                    model=step.model.state_dict(),
                    optimizer=step.optimiser.optimizer.state_dict(),
                    scheduler=step.optimiser.scheduler.state_dict(),
                    generator=self.shuffle.get_state(),
                    best_validation_loss=best.value,
                    best_epoch=best.at,
                    best_model=best.state,
                    history=self.run.history,
                    wall_time_s=self.run.clock.wall_time_s(),
                    ema_model=None if step.ema is None else step.ema.model.state_dict(),
                    epoch_start_generator=None if cursor is None else cursor.start_generator,
                    next_batch=0 if cursor is None else cursor.next_batch,
                    epoch_loss_sum=0.0 if cursor is None else cursor.loss_sum,
                    rank_generators=rank_generators,
                    rank_epoch_loss_sums=rank_loss_sums,
                ),
            )
        self.run.clock.saved()

    def save_if_due(self, epoch: int, cursor: EpochCursor) -> None:
        if self.last_path is None:
            return
        # Rank 0's clock decides: saving gathers from every process.
        if self.processes.agree(self.run.clock.checkpoint_due()):
            self.save(epoch, cursor)


def epoch_pairs(
    config: TrainConfig, data: FlowData, split: Split, epoch: int, device: torch.device
) -> tuple[FlowPairs, float]:
    """The pairs epoch `epoch` trains on (fresh ones with `config.fresh_data` after the
    first), and the seconds labelling them took."""
    labelling_started = time.perf_counter()
    pairs = split.train_pairs
    if config.fresh_data and epoch > 0 and data.labeller is not None:
        fresh = data.labeller(len(split.train_index), fresh_seed(config.seed, epoch))
        pairs = FlowPairs(fresh.q_1.to(device), fresh.condition.to(device))
    return pairs, time.perf_counter() - labelling_started


def shuffled(
    generator: torch.Generator, count: int, cursor: EpochCursor | None, device: torch.device
) -> tuple[EpochCursor, torch.Tensor]:
    """An epoch's cursor and order (count,): a fresh shuffle drawn from `generator`, or
    (`cursor` of a stopped epoch) the shuffle drawn before the stop, `generator` left where
    it stopped."""
    if cursor is None:
        cursor = EpochCursor(generator.get_state())
        return cursor, torch.randperm(count, generator=generator).to(device)
    now = generator.get_state()
    generator.set_state(cursor.start_generator)
    order = torch.randperm(count, generator=generator).to(device)
    generator.set_state(now)
    return cursor, order


@dataclass(frozen=True)
class Epochs:
    """What the epochs of one `train` call run on."""

    config: TrainConfig
    data: FlowData
    split: Split
    step: Optimisation
    evaluated: nn.Module  # validated and kept: the model, or its weight average
    steps_per_epoch: int
    run_dir: Path | None
    processes: Processes


def run_epochs(epochs: Epochs, run: Run, checkpointer: Checkpointer) -> None:
    """Every epoch from `run.first_epoch` on: train, validate, keep the best, log, save."""
    config, split, processes = epochs.config, epochs.split, epochs.processes
    device = split.train_pairs.q_1.device
    resumed_batches = run.resumed_cursor.next_batch if run.resumed_cursor else 0
    with tqdm(
        total=config.epochs * epochs.steps_per_epoch,
        initial=run.first_epoch * epochs.steps_per_epoch + resumed_batches,
        unit="batch",
        mininterval=2.0,
        smoothing=0.0,  # ETA from this process's mean rate, pauses (validation, labels) included
        disable=not processes.is_main,
    ) as progress:
        for epoch in range(run.first_epoch, config.epochs):
            pairs, labelling_s = epoch_pairs(config, epochs.data, split, epoch, device)
            cursor, order = shuffled(
                checkpointer.shuffle, len(split.train_index), run.resumed_cursor, device
            )
            run.resumed_cursor = None
            order = processes.shard(order)
            first_batch, training_started = cursor.next_batch, time.perf_counter()
            train_loss = train_one_epoch(
                epochs.step, pairs, order, cursor, progress,
                after_batch=partial(checkpointer.save_if_due, epoch),
            )  # fmt: skip
            train_loss = processes.mean(train_loss)  # every process ran as many batches
            training_s = time.perf_counter() - training_started
            val_loss = processes.weighted_mean(
                validation_loss(epochs.evaluated, *split.validation)
                if split.validation_rows
                else 0.0,
                split.validation_rows,
            )
            run.history.append(
                {"epoch": epoch, "train_loss": train_loss, "validation_loss": val_loss}
            )
            run.best.offer(val_loss, epoch, epochs.evaluated)
            progress.set_postfix(
                epoch=epoch, train=f"{train_loss:.4f}", validation=f"{val_loss:.4f}"
            )
            if epochs.run_dir is not None and processes.is_main:
                samples = (len(order) - first_batch * config.batch_size) * processes.world_size
                run.log_rows.append(
                    {
                        "epoch": epoch,
                        "steps": (epoch + 1) * epochs.steps_per_epoch,
                        "train_loss": train_loss,
                        "validation_loss": val_loss,
                        "learning_rate": epochs.step.optimiser.learning_rate,
                        "wall_time_s": run.clock.wall_time_s(),
                        "samples_per_s": samples / training_s,
                        "labelling_s": labelling_s,
                    }
                )
                write_log(epochs.run_dir / LOG_FILE, run.log_rows)
                plot_losses(epochs.run_dir / LOSS_PLOT_FILE, run.history)
            checkpointer.save(epoch + 1, None)


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
    if config.fresh_data and data.labeller is None:
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
    data_split = split_data(config, data, generator, processes, device)
    model = build_model(config, data).to(device)
    steps_per_epoch = math.ceil(len(processes.shard(data_split.train_index)) / config.batch_size)
    step = Optimisation(
        model=model,
        network=wrap(model, processes),
        optimiser=Optimiser.cosine_adamw(
            model, config.learning_rate, config.weight_decay, config.epochs * steps_per_epoch
        ),
        ema=None if config.ema_decay == 0 else WeightAverage(model, config.ema_decay),
        generator=noise,
        times=times,
        batch_size=config.batch_size,
        autocast_bf16=config.autocast_bf16,
    )
    evaluated = model if step.ema is None else step.ema.model  # validated, kept, exported
    run = start_run(config, step, evaluated, generator, run_dir, resume, processes)
    last_path = None if run_dir is None else run_dir / LAST_FILE
    checkpointer = Checkpointer(config, step, generator, run, last_path, processes)
    epochs = Epochs(config, data, data_split, step, evaluated, steps_per_epoch, run_dir, processes)
    run_epochs(epochs, run, checkpointer)
    model.load_state_dict(run.best.state)
    return TrainResult(
        model=model.cpu().eval(),
        best_validation_loss=run.best.value,
        best_epoch=run.best.at,
        history=run.history,
        wall_time_s=run.clock.wall_time_s(),
    )
