"""What bounds the batch against its singles, from a `tools.batch_benchmark` result.

Three bounds, per target in ms, each read from the measured result (light imports only, so
the benchmark's report and the docs' pages compute them alike):

- `stage_bound`: the batch's sampling (its targets' network evaluations, as many targets
  at a time as the batch runs) and what lies outside the pipeline (HTTP, validation and
  JSON at both ends), as if correction, connection and summaries took nothing.
- `cpu_bound`: the cores. A batch takes at least its CPU time (the server's and the
  client's processes, every thread) spread over every core; so it gains at most the
  singles' wall time over that. A batch at the goal's ratio could spend at most the cores
  times a third of the singles' wall time per target: the CPU it must save against what
  it spends now is what batching would have to share between targets.
- `network_bound`: where the server evaluates the int8 network on the AVX2 kernel, each
  target's network work (its Euler steps' evaluations of its own rows: an answer equal to
  its single answer needs exactly those products) over the AVX2 product's peak on every
  core, measured in the same run (tools.network_floor: no exact AVX2 kernel multiplies
  faster than vpmaddwd alone). Nothing a batch shares between targets removes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from tools.goals import BATCH_GOAL_X

BATCH_STAGES = ("sample", "correct", "connect", "summarise")


@dataclass(frozen=True)
class StageBound:
    singles_ms: float  # the singles' client wall time per target
    batch_ms: float  # the batch's client wall time per target
    stage_ms: dict[str, float]  # each of BATCH_STAGES, the server's total per target
    outside_ms: float  # client wall time less the server's total, per target
    at_once: int  # targets the batch answers at a time

    @property
    def floor_ms(self) -> float:
        """Sampling over at_once, plus outside."""
        return self.stage_ms["sample"] / self.at_once + self.outside_ms

    @property
    def most_x(self) -> float:
        return self.singles_ms / self.floor_ms


def stage_bound(batch: dict[str, Any]) -> StageBound:
    targets, server = batch["targets"], batch["server_batch_median_ms"]
    at_once = int(batch.get("batch_threads", 1))
    stage_ms = {stage: server.get(stage, 0.0) / targets for stage in BATCH_STAGES}
    return StageBound(
        singles_ms=batch["singles_median_ms"] / targets,
        batch_ms=batch["batch_median_ms"] / targets,
        stage_ms=stage_ms,
        outside_ms=max(batch["batch_median_ms"] - server["total"], 0.0) / targets,
        at_once=at_once,
    )


@dataclass(frozen=True)
class CpuBound:
    cores: int
    singles_ms: float  # the singles' client wall time per target
    singles_cpu_ms: float  # their CPU per target, server and client
    batch_cpu_ms: float  # the batch's CPU per target, server and client

    @property
    def least_ms(self) -> float:
        """batch_cpu_ms over the cores: the batch's least wall time per target."""
        return self.batch_cpu_ms / self.cores

    @property
    def most_x(self) -> float:
        return self.singles_ms / self.least_ms

    @property
    def goal_cpu_ms(self) -> float:
        """The most CPU per target a batch at the goal's ratio could spend."""
        return self.cores * self.singles_ms / BATCH_GOAL_X


def cpu_bound(batch: dict[str, Any]) -> CpuBound | None:
    """None for a result measured without the processes' CPU."""
    if "batch_cpu_median_ms" not in batch:
        return None
    targets = batch["targets"]
    return CpuBound(
        cores=int(batch["cores"]),
        singles_ms=batch["singles_median_ms"] / targets,
        singles_cpu_ms=batch["singles_cpu_median_ms"]["total"] / targets,
        batch_cpu_ms=batch["batch_cpu_median_ms"]["total"] / targets,
    )


def cpu_sentence(cpu: CpuBound, one_thread: CpuBound | None = None) -> str:
    """The cores' bound on the batch, in words (the report's and the docs' pages): the
    default batch's, and the one-thread batch's beside it when measured (the same work
    per target, answered one target at a time)."""
    spent = f"the batch {cpu.batch_cpu_ms:.1f} ms"
    most = f"at most **{cpu.most_x:.2f}x** the singles' {cpu.singles_ms:.1f} ms"
    least_cpu_ms = cpu.batch_cpu_ms
    if one_thread is not None:
        spent += f", and {one_thread.batch_cpu_ms:.1f} ms on one thread (`SMM_BATCH_THREADS=1`)"
        most += f", and **{one_thread.most_x:.2f}x** on one thread"
        least_cpu_ms = min(least_cpu_ms, one_thread.batch_cpu_ms)
    return (
        f"CPU per target (the server's and the client's processes, every thread): the "
        f"singles {cpu.singles_cpu_ms:.1f} ms; {spent}. Spread over {cpu.cores} cores with "
        f"nothing waiting, a batch's CPU takes at least 1/{cpu.cores} of it per target "
        f"({cpu.least_ms:.1f} ms): {most}. At {BATCH_GOAL_X:g}x a batch could spend at most "
        f"{cpu.goal_cpu_ms:.1f} ms of CPU per target, {cpu.goal_cpu_ms / least_cpu_ms:.0%} of "
        "the least a batch spent here: the rest of each target's computation would have to "
        "be work the targets share, where the batch shares only the requests' exchanges."
    )


@dataclass(frozen=True)
class NetworkBound:
    singles_ms: float  # the singles' client wall time per target
    products: int  # the integer products each target's network work needs
    peak_per_s: float  # the AVX2 product's peak on every core, in the same run

    @property
    def least_ms(self) -> float:
        """The products at the peak: the least time a target's network work takes."""
        return self.products / self.peak_per_s * 1e3

    @property
    def most_x(self) -> float:
        return self.singles_ms / self.least_ms


def network_bound(batch: dict[str, Any]) -> NetworkBound | None:
    """None where the run's network was not on the AVX2 kernel (or before it was measured)."""
    if "network_products_per_target" not in batch:
        return None
    return NetworkBound(
        singles_ms=batch["singles_median_ms"] / batch["targets"],
        products=int(batch["network_products_per_target"]),
        peak_per_s=float(batch["avx2_peak_every_core_per_s"]),
    )


def network_sentence(bound: NetworkBound) -> str:
    """The network's bound on the batch, in words (the report's and the docs' pages)."""
    verdict = (
        f"no batch whose answers equal the singles' reaches {BATCH_GOAL_X:g}x on this processor"
        if bound.most_x < BATCH_GOAL_X
        else "this bound does not rule the goal out"
    )
    return (
        f"The network on AVX2: each target's network work needs {bound.products:,} integer "
        f"products, which at the AVX2 product's peak on every core "
        f"({bound.peak_per_s / 1e9:.1f} G a second, measured after each round) take at least "
        f"{bound.least_ms:.1f} ms: at most **{bound.most_x:.2f}x** the singles' "
        f"{bound.singles_ms:.1f} ms, whatever else the targets share, so {verdict}."
    )
