"""The phase profile (`python -m tools.phase_profile`): each phase of an answer timed
whole, its compiled work apart from its Python.

- On iiwa14 pose targets (drawn at once, r = 1: traced), each stage of the answer runs
  once per target and the trace's phases inside `connect`; every row's compiled time
  lies between 0 and its wall time; the stages together take no longer than the answer,
  the trace's phases no longer than the trace, and the stages' compiled work adds up to
  the answer's (nothing compiled runs between the stages).
- Timing changes nothing: the answers with the phases timed are the answers without,
  and every phase's function is put back where the pipeline calls it from.
- The command prints the table and writes the record.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np
import pytest

from service.manifest import REPO_MODELS_DIR
from service.models.registry import load_model
from service.pipeline.run import run
from tools.connect_profile import KernelTimer, queries_for
from tools.phase_profile import PHASES, main, phases_timed, profile_phases
from training.evaluate.targets import uniform_configurations

MODEL = "iiwa14-pose"


def test_the_phases_add_up_within_the_answer() -> None:
    model = load_model(REPO_MODELS_DIR / MODEL, threads=1)
    profile = profile_phases(MODEL, uniform_configurations(model.limits, 3, 11), repeats=2)
    rows = {row.label: row for row in profile.phases}
    stages = ["sample", "correct", "accept", "connect", "summarise"]
    assert all(rows[stage].calls == 1 for stage in stages)
    assert {"trace", "walk the fronts", "densify", "exact paths"} <= set(rows)
    for row in [profile.answer, *profile.phases]:
        assert 0 <= row.compiled_ms <= row.wall_ms + 1e-9, row
    assert sum(rows[s].wall_ms for s in stages) <= profile.answer.wall_ms
    inside_trace = [row for row in profile.phases if row.inside == "trace"]
    assert inside_trace and sum(r.wall_ms for r in inside_trace) <= rows["trace"].wall_ms
    compiled = sum(rows[s].compiled_ms for s in stages)
    assert compiled == pytest.approx(profile.answer.compiled_ms, rel=1e-9)
    assert profile.answer.compiled_ms > 0.2 * profile.answer.wall_ms  # the network, the kernels


def _callers_of(module_name: str, name: str) -> dict[str, object]:
    """Every service module's binding of `name` that is the function `module_name` defines."""
    import sys

    function = getattr(importlib.import_module(module_name), name)
    return {
        m.__name__: getattr(m, name)
        for m in list(sys.modules.values())
        if getattr(m, "__name__", "").startswith("service.") and getattr(m, name, None) is function
    }


def test_timing_changes_no_answer_and_puts_every_function_back() -> None:
    model = load_model(REPO_MODELS_DIR / MODEL, threads=1)
    queries = queries_for(model, uniform_configurations(model.limits, 2, 5))
    plain = [run(model, q) for q in queries]
    before = {p.label: _callers_of(p.module, p.function) for p in PHASES if "." not in p.function}
    assert all(before.values())
    compiled = KernelTimer()
    with compiled.timing(), phases_timed(PHASES, compiled) as spent:
        timed = [run(model, q) for q in queries]
    assert spent["connect"].calls == 2 and spent["connect"].compiled_s > 0
    after = {p.label: _callers_of(p.module, p.function) for p in PHASES if "." not in p.function}
    assert after == before
    for a, b in zip(plain, timed, strict=True):
        assert a.counts == b.counts and len(a.components) == len(b.components)
        for x, y in zip(a.components, b.components, strict=True):
            assert np.array_equal(x.representative_rad, y.representative_rad)


def test_the_command_prints_and_records(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "phases.json"
    assert main(["--model", MODEL, "--targets", "2", "--repeats", "1", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.splitlines()[0].startswith(f"{MODEL}@") and "connect" in printed
    record = json.loads(out.read_text())
    assert record["command"].startswith("python -m tools.phase_profile --model")
    assert record["targets"] == 2 and record["machine"]["cores"] >= 1
    labels = [row["label"] for row in record["phases"]]
    assert labels[0] == "sample" and "summarise" in labels
    for row in record["phases"]:
        assert row["python_ms"] == pytest.approx(row["wall_ms"] - row["compiled_ms"])
