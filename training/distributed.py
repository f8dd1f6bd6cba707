"""Training one model in several processes: PyTorch's DistributedDataParallel under torchrun.

    torchrun --standalone --nproc-per-node 2 --no-python smm-train train \
        --robot planar3r --task position

torchrun starts the processes and tells each its rank through the environment
(`from_environment`); `process_group` joins them (gloo on the CPU, nccl on CUDA, one GPU per
process); `wrap` puts the model in DistributedDataParallel, which averages the gradients of
every step over the processes. Every process draws the same shuffle of the training split
each epoch and trains on its own `shard` of it, with its own noise and flow times. Run as
one process (plain `smm-train train`, or torchrun with one), nothing here changes anything: every
helper is then the identity and no process group is made.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

import torch
import torch.distributed as dist
from torch import nn
from torch.nn.parallel import DistributedDataParallel

T = TypeVar("T")


@dataclass(frozen=True)
class Processes:
    """Where this process stands among those training the model (torchrun's variables)."""

    rank: int = 0  # 0 writes the checkpoints, the logs and the export
    world_size: int = 1  # processes in all, over every node
    local_rank: int = 0  # on this node: the GPU index on CUDA
    local_world_size: int = 1  # processes on this node (torchrun's --nproc-per-node)

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def device(self, device: str) -> torch.device:
        """This process's device: on CUDA, distributed, its own GPU (cuda:<local rank>)."""
        chosen = torch.device(device)
        if self.distributed and chosen.type == "cuda":
            return torch.device("cuda", self.local_rank)
        return chosen

    def launcher(self) -> list[str]:
        """The command that starts this set of processes, up to the subcommand and its arguments.

        Rendezvous flags (--standalone, --master-port, ...) are left out: they decide where
        the processes meet, not what they train."""
        if not self.distributed:
            return ["smm-train"]
        nodes = self.world_size // self.local_world_size
        per_node = ["--nproc-per-node", str(self.local_world_size)]
        return ["torchrun", *(["--nnodes", str(nodes)] if nodes > 1 else []), *per_node,
                "--no-python", "smm-train"]  # fmt: skip

    def shard(self, order: torch.Tensor) -> torch.Tensor:
        """This process's part of an epoch's shuffled order (N,): see `shard`."""
        return shard(order, self.rank, self.world_size)

    def part(self, count: int) -> slice:
        """This process's contiguous part of `count` rows (the validation split); parts of
        ranks 0..K-1 in order make up all rows; slice(None) for one process."""
        if not self.distributed:
            return slice(None)
        bounds = [count * r // self.world_size for r in range(self.world_size + 1)]
        return slice(bounds[self.rank], bounds[self.rank + 1])

    # Collectives: every process must call them at the same point, in the same order.

    def mean(self, value: float) -> float:
        """The mean over the processes of each one's `value`."""
        if not self.distributed:
            return value
        return self._sum(value) / self.world_size

    def weighted_mean(self, value: float, weight: float) -> float:
        """sum(value * weight) / sum(weight) over the processes."""
        if not self.distributed:
            return value
        return self._sum(value * weight) / self._sum(weight)

    def agree(self, flag: bool) -> bool:
        """Rank 0's `flag`, on every process (for decisions made by the clock)."""
        if not self.distributed:
            return flag
        box = torch.tensor([int(flag)], device=_collective_device())
        dist.broadcast(box, src=0)
        return bool(box.item())

    def gather(self, value: T) -> list[T]:
        """Every process's `value`, by rank (any picklable object)."""
        if not self.distributed:
            return [value]
        values: list[Any] = [None] * self.world_size
        dist.all_gather_object(values, value)
        return values

    def from_main(self, make: Callable[[], T]) -> T:
        """`make()` run by rank 0 alone (it may write files), its result sent to every process."""
        if not self.distributed:
            return make()
        box: list[Any] = [make() if self.is_main else None]
        dist.broadcast_object_list(box, src=0)
        return box[0]

    def _sum(self, value: float) -> float:
        total = torch.tensor([value], dtype=torch.float64, device=_collective_device())
        dist.all_reduce(total)
        return float(total.item())


SINGLE = Processes()


def from_environment() -> Processes:
    """The processes torchrun started (RANK, WORLD_SIZE, LOCAL_RANK, LOCAL_WORLD_SIZE); one
    process when they are not set."""
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size == 1:
        return SINGLE
    return Processes(
        rank=int(os.environ["RANK"]),
        world_size=world_size,
        local_rank=int(os.environ.get("LOCAL_RANK", os.environ["RANK"])),
        local_world_size=int(os.environ.get("LOCAL_WORLD_SIZE", str(world_size))),
    )


@contextmanager
def process_group(processes: Processes, device: str) -> Iterator[None]:
    """Joined with the other processes inside (gloo for a CPU device, nccl for CUDA, each
    process on GPU <local rank>); torchrun's MASTER_ADDR and MASTER_PORT say where to meet.
    Nothing happens for one process."""
    if not processes.distributed:
        yield
        return
    cuda = torch.device(device).type == "cuda"
    if cuda:
        torch.cuda.set_device(processes.local_rank)
    dist.init_process_group(
        backend="nccl" if cuda else "gloo", rank=processes.rank, world_size=processes.world_size
    )
    try:
        yield
    finally:
        dist.destroy_process_group()


def wrap(model: nn.Module, processes: Processes) -> nn.Module:
    """What the training forward pass runs through: `model` itself for one process; for
    several, DistributedDataParallel, which makes the weights equal at the start (rank 0's)
    and averages the gradients of every backward pass over the processes."""
    if not processes.distributed:
        return model
    on_gpu = next(model.parameters()).device
    return DistributedDataParallel(
        model, device_ids=[on_gpu.index] if on_gpu.type == "cuda" else None
    )


def shard(order: torch.Tensor, rank: int, world_size: int) -> torch.Tensor:
    """Rank `rank`'s part of an epoch's order (N,) among `world_size` processes: every
    world_size-th entry from position `rank` (torch's DistributedSampler's split), after
    dropping the last N mod world_size entries so that every process runs the same number
    of batches (DDP steps in lockstep). The parts are disjoint and, with the same order on
    every process, cover all but those N mod world_size entries; one process keeps `order`."""
    if world_size == 1:
        return order
    usable = len(order) - len(order) % world_size
    return order[rank:usable:world_size]


def _collective_device() -> torch.device:
    """Where a collective's tensors live: the current GPU under nccl, else the CPU."""
    if dist.get_backend() == "nccl":
        return torch.device("cuda", torch.cuda.current_device())
    return torch.device("cpu")
