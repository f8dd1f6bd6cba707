"""What bounds the batch against its singles, from a `tools.batch_benchmark` result (and a
`tools.batch_processes` record: `processes_sentence`).

Five bounds, per target in ms, each read from the measured result (light imports only, so
the benchmark's report and the docs' pages compute them alike):

- `stage_bound`: the batch's sampling (its targets' network evaluations, as many targets
  at a time as the batch runs) and what lies outside the pipeline (HTTP, validation and
  JSON at both ends), as if correction, connection and summaries took nothing.
- `cpu_bound`: the cores. A batch takes at least its CPU time (the server's and the
  client's processes, every thread) spread over every core; so it gains at most the
  singles' wall time over that. A batch at the goal's ratio could spend at most the cores
  times a third of the singles' wall time per target: the CPU it must save against what
  it spends now is what batching would have to share between targets.
- `compiled_bound`: the compiled work. Each target's answer calls the compiled kernels
  and the flow network on its own rows, encodes its JSON, and the client reads it
  (`tools.batch_benchmark.compiled_work`, in process on one thread, and the client's CPU
  in the batch): spread over every core, that takes at least its sum even if a batch
  shared every line of the pipeline's Python and numpy between its targets at no cost.
- `same_work_bound`: faster answers alone. Were every target's answer cheaper by the same
  factor in the singles and the batch (compiled code for the pipeline's Python, faster
  kernels), with nothing shared between a batch's targets, a single would still spend
  what lies outside its answer (HTTP, validation, JSON and the client's reading) one
  request after another, and the batch its encoding and the client's reading over the
  cores: the ratio the batch could reach as a function of an answer's CPU, and the most
  an answer could cost for the goal's.
- `network_bound`: where the server evaluates the int8 network on the AVX2 kernel, each
  target's network work (its Euler steps' evaluations of its own rows: an answer equal to
  its single answer needs exactly those products) over the AVX2 product's peak on every
  core, measured in the same run (tools.network_floor: no exact AVX2 kernel multiplies
  faster than vpmaddwd alone). Nothing a batch shares between targets removes it.

And what the GIL costs: `processes_sentence` reads the same targets answered in process
one after another, on the service's batch threads and on as many processes
(`tools.batch_processes`); what the processes save over the threads is the time a batch's
threads spend waiting for one another's Python.
"""

from __future__ import annotations

import math
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
class CompiledBound:
    cores: int
    singles_ms: float  # the singles' client wall time per target
    answer_ms: float  # a target's whole answer in process on one thread
    compiled_ms: float  # its compiled kernels and flow network on one thread
    encode_ms: float  # its answer's JSON encoding
    client_ms: float  # the client's CPU per target in the batch

    @property
    def unshared_ms(self) -> float:
        """CPU per target that no sharing between targets removes."""
        return self.compiled_ms + self.encode_ms + self.client_ms

    @property
    def least_ms(self) -> float:
        return self.unshared_ms / self.cores

    @property
    def most_x(self) -> float:
        return self.singles_ms / self.least_ms


def compiled_bound(batch: dict[str, Any]) -> CompiledBound | None:
    """None for a result measured without the compiled work or the processes' CPU."""
    work = batch.get("compiled_work_ms")
    if work is None or "batch_cpu_median_ms" not in batch:
        return None
    targets = batch["targets"]
    return CompiledBound(
        cores=int(batch["cores"]),
        singles_ms=batch["singles_median_ms"] / targets,
        answer_ms=float(work["answer"]),
        compiled_ms=float(work["compiled"]),
        encode_ms=float(work["encode"]),
        client_ms=batch["batch_cpu_median_ms"]["client"] / targets,
    )


def compiled_sentence(bound: CompiledBound) -> str:
    """The compiled work's bound on the batch, in words (the report's and the docs' pages)."""
    verdict = (
        f"so sharing the Python alone cannot reach {BATCH_GOAL_X:g}x here: the compiled work "
        "itself, the answers' encoding or the client's reading must get cheaper"
        if bound.most_x < BATCH_GOAL_X
        else "so this bound does not rule the goal out"
    )
    shareable_ms = max(bound.answer_ms - bound.compiled_ms, 0.0)
    return (
        f"What no sharing between targets removes: each target's answer takes "
        f"{bound.answer_ms:.1f} ms in process on one thread, {bound.compiled_ms:.1f} ms of it "
        f"in the compiled kernels and the flow network on its own rows (the other "
        f"{shareable_ms:.1f} ms, the pipeline's Python and numpy between those calls, is all "
        f"a batch could share); its JSON encoding takes {bound.encode_ms:.1f} ms and the "
        f"client's reading of it {bound.client_ms:.1f} ms of CPU. Even with that Python "
        f"shared at no cost, {bound.unshared_ms:.1f} ms of CPU per target over {bound.cores} "
        f"cores takes at least {bound.least_ms:.1f} ms: at most **{bound.most_x:.2f}x** the "
        f"singles' {bound.singles_ms:.1f} ms, {verdict}."
    )


@dataclass(frozen=True)
class SameWorkBound:
    cores: int
    singles_ms: float  # the singles' client wall time per target
    single_answer_ms: float  # a single's answer on the server (its stages' total), per target
    answer_ms: float  # a target's whole answer in process on one thread: its CPU
    compiled_ms: float  # its compiled kernels and flow network on one thread
    encode_ms: float  # its answer's JSON encoding
    client_ms: float  # the client's CPU per target in the batch

    @property
    def outside_ms(self) -> float:
        """What a single spends beyond its answer: HTTP, validation, JSON, the client."""
        return max(self.singles_ms - self.single_answer_ms, 0.0)

    @property
    def wall_per_cpu(self) -> float:
        """A single's answer's wall time over its CPU on one thread (under 1 where its
        calls run on more than one thread); taken to hold at any answer cost."""
        return self.single_answer_ms / self.answer_ms

    def most_x(self, answer_cpu_ms: float) -> float:
        """The most a batch gains were every answer to cost `answer_cpu_ms` of CPU in both:
        the singles' wall time then over the batch's CPU then spread over the cores."""
        singles_ms = self.outside_ms + self.wall_per_cpu * answer_cpu_ms
        least_ms = (answer_cpu_ms + self.encode_ms + self.client_ms) / self.cores
        return singles_ms / least_ms

    @property
    def goal_answer_ms(self) -> float | None:
        """The most CPU an answer could cost for the goal's ratio; None where not even free
        answers reach it, infinity where every cost does."""
        per_core = BATCH_GOAL_X / self.cores
        spare_ms = self.outside_ms - per_core * (self.encode_ms + self.client_ms)
        if spare_ms < 0:
            return None
        if per_core <= self.wall_per_cpu:
            return math.inf
        return spare_ms / (per_core - self.wall_per_cpu)


def same_work_bound(batch: dict[str, Any]) -> SameWorkBound | None:
    """None for a result measured without the singles' server time, the compiled work or
    the processes' CPU."""
    work = batch.get("compiled_work_ms")
    if work is None or "singles_server_median_ms" not in batch:
        return None
    if "batch_cpu_median_ms" not in batch:
        return None
    targets = batch["targets"]
    return SameWorkBound(
        cores=int(batch["cores"]),
        singles_ms=batch["singles_median_ms"] / targets,
        single_answer_ms=batch["singles_server_median_ms"] / targets,
        answer_ms=float(work["answer"]),
        compiled_ms=float(work["compiled"]),
        encode_ms=float(work["encode"]),
        client_ms=batch["batch_cpu_median_ms"]["client"] / targets,
    )


def same_work_sentence(bound: SameWorkBound) -> str:
    """Faster answers' bound on the batch, in words (the report's and the docs' pages)."""
    goal_ms = bound.goal_answer_ms
    if goal_ms is None:
        needs = (
            f"not even free answers reach {BATCH_GOAL_X:g}x: the answers' transport must get "
            "cheaper, or the targets share work"
        )
    elif math.isinf(goal_ms):
        needs = f"any answer cost reaches {BATCH_GOAL_X:g}x"
    else:
        needs = (
            f"{BATCH_GOAL_X:g}x needs answers of at most {goal_ms:.1f} ms of CPU, "
            f"{bound.answer_ms / goal_ms:.1f} times cheaper than now, "
            + (
                "less than the compiled work alone: compiled code for the Python is not "
                "enough, the kernels must get cheaper too, or the targets share work"
                if goal_ms < bound.compiled_ms
                else "within what compiled code for the Python would give"
            )
        )
    return (
        f"Faster answers alone, the same work per target in the singles and the batch and "
        f"nothing shared: a single spends {bound.outside_ms:.1f} ms per target outside its "
        f"answer (HTTP, validation, JSON and the client's reading) and "
        f"{bound.single_answer_ms:.1f} ms on it, whose CPU on one thread is "
        f"{bound.answer_ms:.1f} ms. Were every answer cheaper by the same factor in both, a "
        f"single's wall time on it shrinking alike, the batch over {bound.cores} cores would "
        f"gain at most **{bound.most_x(bound.compiled_ms):.2f}x** with the pipeline's Python "
        f"gone from every answer ({bound.compiled_ms:.1f} ms of CPU each) and "
        f"**{bound.most_x(0.0):.2f}x** with answers free; {needs}."
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


def processes_sentence(record: dict[str, Any]) -> str:
    """A `tools.batch_processes` record in one paragraph, as its console and the speed page
    print it."""
    one = record["one_after_another_ms_per_target"]
    threads, processes = record["threads_ms_per_target"], record["processes_ms_per_target"]
    mismatched = record["mismatched"]
    same = f"answers differing on targets {mismatched}" if mismatched else "the same answers"
    return (
        f"{record['targets']} targets of {record['model']} at N = {record['num_samples']}, in "
        f"process: {one:.1f} ms a target one after another, {threads:.1f} ms on the "
        f"service's {record['threads']} batch threads ({one / threads:.2f}x), "
        f"{processes:.1f} ms on {record['processes']} processes ({one / processes:.2f}x), "
        f"with {same}. The threads take {threads / processes:.2f}x the processes' time: "
        f"{1 - processes / threads:.0%} of the threads' batch is what sharing one process "
        "costs them (its lock on the interpreter, the GIL: one thread's Python at a time)."
    )
