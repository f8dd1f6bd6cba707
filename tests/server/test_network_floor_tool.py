"""The network floor (`python -m tools.network_floor`): per bundled int8 network, the products
a row are the layers' k x n, the floor is the default request's evaluations of its least
rows times those products over the every-core peak, and at the goals' N the same with its
least rows there (one round's for a model drawing in rounds), the arithmetic checked here
apart; the goal is the one tools.goals sets, and a run writes every model whose served
sampler is int8 into its report."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from service.models.int8_mlp import usable_kernels
from tools import network_floor
from tools.goals import GOAL_NUM_SAMPLES, GOALS

pytestmark = pytest.mark.skipif("avx2" not in usable_kernels(), reason="no AVX2 here")


def _manifest(model_id: str) -> Manifest:
    return Manifest.model_validate_json((REPO_MODELS_DIR / model_id / MANIFEST_FILE).read_bytes())


def test_the_floor_is_the_requests_products_over_the_every_core_peak() -> None:
    measured = network_floor.measure(REPO_MODELS_DIR / "planar3r-position", rounds=1, seed=0)
    manifest = _manifest("planar3r-position")
    # the count itself is checked against the onnx package's reading in test_int8_mlp
    assert measured["products_per_row"] > 0
    assert measured["evaluations"] == manifest.defaults.sampler.steps
    # planar 3R draws in rounds: a request evaluates one round's rows at least
    assert manifest.defaults.sampler.round_samples is not None
    assert measured["least_rows"] == manifest.defaults.sampler.round_samples
    assert measured["least_rows_goal_n"] == manifest.defaults.sampler.round_samples
    assert 0 < measured["efficiency"] < math.inf and measured["call_ms"] > 0
    floored = network_floor.with_floor(measured, every_core_per_s=1e10)
    products = measured["evaluations"] * measured["products_per_row"]
    assert floored["floor_ms"] == pytest.approx(products * measured["least_rows"] / 1e10 * 1e3)
    # at the goals' N too: its first round of 128 rows, not all 1000
    rows = manifest.defaults.sampler.round_samples
    assert floored["floor_goal_n_ms"] == pytest.approx(products * rows / 1e10 * 1e3)
    assert floored["goal_ms"] == dict((m, ms) for m, ms, _ in GOALS)["planar3r-position"]


def test_a_model_without_rounds_evaluates_its_num_samples() -> None:
    manifest = _manifest("iiwa14-pose")
    assert manifest.defaults.sampler.round_samples is None
    assert network_floor.least_rows(manifest) == manifest.defaults.num_samples
    assert network_floor.least_rows(manifest, GOAL_NUM_SAMPLES) == GOAL_NUM_SAMPLES


def test_a_run_reports_every_model_served_int8(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "floor.json"
    monkeypatch.setattr(sys, "argv", ["network_floor", "--rounds", "1", "--json", str(out)])
    monkeypatch.setattr(network_floor, "PROBE_S", 0.01)
    monkeypatch.setattr(network_floor, "CALLS", 1)
    network_floor.main()
    report = json.loads(out.read_text())
    int8_served = {
        p.parent.name
        for p in REPO_MODELS_DIR.glob(f"*/{MANIFEST_FILE}")
        if _manifest(p.parent.name).defaults.sampler.precision == "int8"
    }
    assert {r["model"] for r in report["results"]} == int8_served
    assert report["peak_every_core_per_s"] > 0 and report["command"].endswith(str(out))
