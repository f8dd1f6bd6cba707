"""Two training processes on the CPU, started as torchrun would start them (gloo, env://).

`run_two_processes(worker, out_dir)` runs `worker(out_dir)` in two spawned processes with
torchrun's variables set (RANK, WORLD_SIZE, LOCAL_RANK, LOCAL_WORLD_SIZE, MASTER_ADDR,
MASTER_PORT on a free port) and re-raises the first failure. Workers save what they saw to
`out_dir/rank<r>.pt` for the test to read.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import torch
import torch.multiprocessing as mp

from tests.support.tiny_training import TINY, tiny_planar_data
from training import train as train_module
from training.distributed import from_environment, process_group
from training.train import train

WORLD_SIZE = 2
# TINY in two processes, last.pt after every batch: each process has 270 of the 540
# training samples, 3 batches (128, 128, 14) an epoch, mid-epoch saves after 2 of them.
TWO = replace(TINY, world_size=WORLD_SIZE, checkpoint_minutes=0.0)
STOP_AT = (1, 2)  # the stopped run ends after epoch 1's second batch (and its save)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def run_two_processes(worker: Callable[[Path], None], out_dir: Path) -> None:
    mp.start_processes(
        _as_rank,
        args=(worker, out_dir, free_port()),
        nprocs=WORLD_SIZE,
        join=True,
        start_method="spawn",
    )


def _as_rank(rank: int, worker: Callable[[Path], None], out_dir: Path, port: int) -> None:
    os.environ.update(
        RANK=str(rank),
        LOCAL_RANK=str(rank),
        WORLD_SIZE=str(WORLD_SIZE),
        LOCAL_WORLD_SIZE=str(WORLD_SIZE),
        MASTER_ADDR="127.0.0.1",
        MASTER_PORT=str(port),
    )
    torch.set_num_threads(1)
    worker(out_dir)


def train_whole_stopped_and_resumed(out_dir: Path) -> None:
    """In one process group: TWO trained whole (run dir out_dir/whole), then stopped at
    STOP_AT (out_dir/stopped) and resumed there. Saved per rank: this process's order (its
    shard) and noise generator seed in every epoch of each run, the two results, and how
    many times this process wrote last.pt and log.jsonl."""
    processes = from_environment()
    data = tiny_planar_data()
    now: dict[str, Any] = {}  # the run under way, its next epoch, whether it is to stop
    seen: list[dict[str, Any]] = []
    writes = {"save_state": 0, "write_log": 0}
    real_epoch = train_module.train_one_epoch

    def recording(
        step: Any, pairs: Any, order: torch.Tensor, cursor: Any, progress: Any,
        after_batch: Callable[[Any], None],
    ) -> float:  # fmt: skip
        epoch = now["epoch"]
        now["epoch"] += 1
        seen.append({"run": now["run"], "epoch": epoch, "order": order.clone(),
                     "noise_seed": step.generator.initial_seed()})  # fmt: skip

        def then_maybe_stop(at: Any) -> None:
            after_batch(at)
            if now["stop"] and (epoch, at.next_batch) == STOP_AT:
                raise KeyboardInterrupt  # on every process, after the same save

        return real_epoch(step, pairs, order, cursor, progress, after_batch=then_maybe_stop)

    def counting(name: str, real: Callable[..., None]) -> Callable[..., None]:
        def counted(*args: Any) -> None:
            writes[name] += 1
            real(*args)

        return counted

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(train_module, "train_one_epoch", recording)
        patch.setattr(train_module, "save_state", counting("save_state", train_module.save_state))
        patch.setattr(train_module, "write_log", counting("write_log", train_module.write_log))
        with process_group(processes, "cpu"):
            now.update(run="whole", epoch=0, stop=False)
            whole = train(TWO, data, run_dir=out_dir / "whole", processes=processes)
            now.update(run="stopped", epoch=0, stop=True)
            try:
                train(TWO, data, run_dir=out_dir / "stopped", processes=processes)
            except KeyboardInterrupt:
                pass
            else:
                raise AssertionError("the stopped run did not stop")
            now.update(run="resumed", epoch=STOP_AT[0], stop=False)
            resumed = train(
                TWO, data, run_dir=out_dir / "stopped", resume=True, processes=processes
            )
    torch.save(
        {
            "seen": seen,
            "writes": writes,
            "whole": whole,
            "resumed": resumed,
        },
        out_dir / f"rank{processes.rank}.pt",
    )
