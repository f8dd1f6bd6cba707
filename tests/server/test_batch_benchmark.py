"""tools.batch_benchmark: K targets as one POST /smm/batch (read as lines, and as one JSON
object) against K single POST /smm on a real server; every batch answer of both forms is
checked against its single answer, and a differing
answer is caught by index; each phase's CPU time is the server's and the client's, as the
kernel counts a process's (`tools.procfs.cpu_seconds`, checked against the clock
Python reads for its own process); where AVX2 serves the int8 network, the run records
each target's network products (steps x rows x the layers' products a row) and the AVX2
peak."""

from __future__ import annotations

import os
import time

import pytest

from service.api.answers import encode
from service.api.smm import smm_fields
from service.api.smm_batch import batch_fields
from service.models.int8_mlp import CompiledVelocityField
from service.models.registry import ServedModel
from service.pipeline.batch import BatchResult
from service.pipeline.run import run
from service.pipeline.types import Query
from service.wire import SmmBatchResponse, SmmResponse
from tools.batch_benchmark import batch_against_singles, mismatched_targets
from tools.procfs import cpu_seconds
from training.evaluate.targets import uniform_configurations


def test_batch_against_singles_times_both_and_finds_the_answers_identical(
    planar3r: ServedModel,
) -> None:
    limits = planar3r.limits
    q_targets = uniform_configurations(limits, 3, seed=7)
    result = batch_against_singles(planar3r, q_targets, num_samples=100, rounds=2)
    assert result["identical"] is True and result["mismatched"] == []
    assert result["targets"] == 3 and result["num_samples"] == 100
    assert result["served_default"] is False
    assert len(result["singles_ms"]) == len(result["batch_ms"]) == 2
    assert len(result["batch_json_ms"]) == 2  # the same batch asked as one JSON object
    assert result["singles_median_ms"] > 0 and result["batch_median_ms"] > 0
    ratio = result["singles_median_ms"] / result["batch_median_ms"]
    assert result["singles_over_batch"] == ratio
    json_ratio = result["singles_median_ms"] / result["batch_json_median_ms"]
    assert result["singles_over_batch_json"] == json_ratio
    assert result["server_batch_median_ms"]["total"] > 0
    # The singles' answers on the server take part of the client's wall time around them.
    assert 0 < result["singles_server_median_ms"] < result["singles_median_ms"]
    assert result["model"].startswith("planar3r-position@")
    for phase in ("singles_cpu_median_ms", "batch_cpu_median_ms"):
        cpu = result[phase]
        # The server answers every target; the client at least parses every answer.
        assert cpu["server"] > 0 and cpu["client"] > 0
        # each key's median over the rounds (2: their mean), so the total's to round-off
        assert cpu["total"] == pytest.approx(cpu["server"] + cpu["client"])
    assert result["cores"] == os.cpu_count()
    # The network's products a target, and the AVX2 peak, where AVX2 serves the network.
    served = planar3r.networks[planar3r.manifest.defaults.sampler.file]
    on_avx2 = isinstance(served, CompiledVelocityField) and served.kernel == "avx2"
    assert ("network_products_per_target" in result) == on_avx2
    if isinstance(served, CompiledVelocityField) and on_avx2:
        steps = planar3r.manifest.defaults.sampler.steps
        rows = min(100, planar3r.manifest.defaults.sampler.round_samples or 100)
        expected = steps * rows * served.layers.products_per_row
        assert result["network_products_per_target"] == expected
        assert result["avx2_peak_every_core_per_s"] > 0


def test_batch_at_the_served_default_asks_without_num_samples(planar3r: ServedModel) -> None:
    """num_samples None: the requests carry none, so the server answers at the model's
    served default N, which the record names; the answers still match the singles'."""
    q_targets = uniform_configurations(planar3r.limits, 2, seed=7)
    result = batch_against_singles(planar3r, q_targets, num_samples=None, rounds=1)
    assert result["served_default"] is True
    assert result["num_samples"] == planar3r.manifest.defaults.num_samples
    assert result["identical"] is True


def test_cpu_seconds_is_the_kernels_count_of_the_process() -> None:
    """/proc's user and system ticks of this process grow with the CPU clock Python reads
    for it (a different source: clock_gettime of the process's CPU time), to a tick."""
    pid = os.getpid()
    before_proc, before_clock = cpu_seconds(pid), time.process_time()
    deadline = time.process_time() + 0.3
    while time.process_time() < deadline:
        pass
    spent_proc, spent_clock = cpu_seconds(pid) - before_proc, time.process_time() - before_clock
    tick_s = 1 / os.sysconf("SC_CLK_TCK")
    assert spent_clock >= 0.3
    assert abs(spent_proc - spent_clock) <= 2 * tick_s + 0.01


def test_a_batch_answer_that_differs_from_its_single_is_named(planar3r: ServedModel) -> None:
    query = Query.for_model(planar3r.manifest, position_m=[0.5, 0.0], num_samples=100)
    result = run(planar3r, query)
    answer = SmmResponse.model_validate_json(encode(smm_fields(planar3r, query, result)))
    singles = [answer, answer.model_copy(update={"timings_ms": {"total": 2.0}})]
    fields = batch_fields(planar3r, [query, query], BatchResult([result, result], None, 1.0))
    batch = SmmBatchResponse.model_validate_json(encode(fields))
    assert mismatched_targets(batch, singles) == []  # timings aside
    changed = batch.model_copy(deep=True)
    changed_answer = changed.results[1].answer
    assert changed_answer is not None
    changed_answer.components[0].size += 1
    assert mismatched_targets(changed, singles) == [1]
    changed.results[0].answer = None  # not answered (deadline)
    assert mismatched_targets(changed, singles) == [0, 1]
