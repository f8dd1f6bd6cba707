"""quality: the figures an export records in its manifest, from the service's own stages.

Raw errors at the serving sampler and at the paper's 100 Euler steps, a keep rate over
every sample, and the same figures for the same seed; a paper-sampler row measured before
is kept as it was, and equals the one measured again; the raw error is the network's of
the sampler's precision.
"""

from __future__ import annotations

import numpy as np
import pytest

from service.manifest import SamplerSpec
from service.models.registry import ServedModel
from training.evaluate.quality import PAPER_SAMPLER, measure_quality, summarise_raw
from training.evaluate.served import with_defaults

TWENTY = SamplerSpec(steps=20)


def test_quality_reports_both_samplers_and_reproduces_for_a_seed(planar3r: ServedModel) -> None:
    quality = measure_quality(planar3r, num_targets=3, samples=100, seed=5)
    default = planar3r.manifest.defaults.sampler
    paper = [PAPER_SAMPLER] if default != PAPER_SAMPLER else []
    assert [(r.sampler_steps, r.sampler_time_power) for r in quality.raw] == [
        (s.steps, s.time_power) for s in [default, *paper]
    ]
    assert quality.held_out_targets == 3 and quality.samples_per_target == 100
    assert 0.0 < quality.keep_rate <= 1.0 and quality.targets_with_solution == 1.0
    assert all(r.orientation_error_deg_mean is None for r in quality.raw)  # position task
    assert measure_quality(planar3r, num_targets=3, samples=100, seed=5) == quality


def test_a_known_paper_row_is_kept_and_is_the_row_measured_again(planar3r: ServedModel) -> None:
    measured = measure_quality(planar3r, num_targets=3, samples=100, seed=5)
    paper_row = measured.raw[-1]
    assert (paper_row.sampler_steps, paper_row.sampler_precision) == (100, "float32")
    kept = measure_quality(planar3r, num_targets=3, samples=100, seed=5, paper_row=paper_row)
    assert kept == measured
    with pytest.raises(ValueError, match="another sampler"):
        measure_quality(planar3r, 3, 100, 5, paper_row=measured.raw[0])


def test_the_raw_error_is_the_network_of_the_sampler_precision(planar3r: ServedModel) -> None:
    def sampler_of(precision: str) -> ServedModel:
        sampler = SamplerSpec(steps=20, precision=precision)
        return with_defaults(planar3r, sampler=sampler)

    int8, float32 = (measure_quality(sampler_of(p), 3, 100, 5) for p in ("int8", "float32"))
    assert (int8.raw[0].sampler_precision, float32.raw[0].sampler_precision) == ("int8", "float32")
    # Different networks, so different errors, but the same paper row (float32 both).
    assert int8.raw[0].position_error_mm_mean != float32.raw[0].position_error_mm_mean
    assert int8.raw[1] == float32.raw[1]


def test_paper_figures_follow_their_definitions_on_hand_made_errors() -> None:
    """Kept-only: samples with (e_p + e_o) / 2 < 0.02, means over them; best-of-N: the mean
    over targets of each target's smallest e_p (here, reach 2 m)."""
    position_m = np.array([[0.02, 0.08, 0.2], [0.04, 0.01, 0.5]])  # (T=2, N=3)
    orientation_rad = np.array([[0.0, 0.0, 0.0], [0.05 * np.pi, 0.0, 0.0]])
    raw = summarise_raw(TWENTY, position_m, orientation_rad, reach_m=2.0, pose=True)
    # e_p = [[.01, .04, .1], [.02, .005, .25]], e_o = [[0, 0, 0], [.05, 0, 0]]
    # e = [[.005, .02, .05], [.035, .0025, .125]]: kept (< 0.02) are (0, 0) and (1, 1)
    assert raw.kept_only_fraction == pytest.approx(2 / 6)
    assert raw.kept_only_position_error_pct_reach_mean == pytest.approx((1.0 + 0.5) / 2)
    assert raw.kept_only_orientation_error_pct_mean == pytest.approx(0.0)
    assert raw.best_of_n_position_error_pct_reach_mean == pytest.approx((1.0 + 0.5) / 2)
    assert raw.position_error_pct_reach_mean == pytest.approx(e_p_mean(position_m, 2.0))
    position_only = summarise_raw(TWENTY, position_m, orientation_rad * 0, reach_m=2.0, pose=False)
    assert position_only.kept_only_fraction == pytest.approx(2 / 6)  # e = e_p: .01, .005
    assert position_only.kept_only_orientation_error_pct_mean is None


def e_p_mean(position_m: np.ndarray, reach_m: float) -> float:
    return float(position_m.mean() / reach_m * 100)
