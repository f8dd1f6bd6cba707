"""quality: the figures an export records in its manifest, from the service's own stages.

Raw errors at the serving sampler and at the paper's 100 Euler steps, a keep rate over
every sample, and the same figures for the same seed.
"""

from __future__ import annotations

from service.models.registry import ServedModel
from training.evaluate.quality import PAPER_SAMPLER_STEPS, measure_quality


def test_quality_reports_both_samplers_and_reproduces_for_a_seed(planar3r: ServedModel) -> None:
    quality = measure_quality(planar3r, num_targets=3, samples=100, seed=5)
    default_steps = planar3r.manifest.defaults.sampler.steps
    paper = [PAPER_SAMPLER_STEPS] if default_steps != PAPER_SAMPLER_STEPS else []
    assert [r.sampler_steps for r in quality.raw] == [default_steps, *paper]
    assert quality.held_out_targets == 3 and quality.samples_per_target == 100
    assert 0.0 < quality.keep_rate <= 1.0 and quality.targets_with_solution == 1.0
    assert all(r.orientation_error_deg_mean is None for r in quality.raw)  # position task
    assert measure_quality(planar3r, num_targets=3, samples=100, seed=5) == quality
