"""paired: a candidate's figure against the incumbent's over the same targets and draws.

- The gain's z is the paired t statistic of the per-target means (scipy's ttest_rel), in
  the figure's units where a target holds several (recall over components).
- The same sampler against itself on other draws is refused by the mean test about one
  time in a hundred (Z_REFUSE's one-sided 1 %), counted over simulated judgements of
  200 targets; a unit lost on every draw happens for it within the 4^-S bound.
- A candidate that loses one target for good (wrong on every draw where the incumbent is
  right on every draw) is refused through the lost unit, though its mean gain is within
  the draws' spread; one that is worse on every target by the same amount has z = -inf.
- `together`: the z of several independent target sets combined is Stouffer's (scipy's
  combine_pvalues); two sets each short of the refusal in the same direction refuse
  together, and one set's z is itself.
"""

import numpy as np
import pytest
from scipy import stats

from training.evaluate.paired import Z_REFUSE, Counts, Paired, paired, together

TARGETS, DRAWS = 200, 4


def _per_target(
    candidate: np.ndarray, incumbent: np.ndarray, more_is_better: bool = True
) -> Paired:
    """paired() of a figure with one unit a target, right where the sum is positive."""
    units, unit_target = np.ones(len(candidate)), np.arange(len(candidate))
    return paired(
        Counts(candidate, units, candidate > 0, unit_target),
        Counts(incumbent, units, incumbent > 0, unit_target), more_is_better,
    )  # fmt: skip


def test_z_is_the_paired_t_statistic_of_the_per_target_means() -> None:
    rng = np.random.default_rng(1)
    candidate = rng.poisson(0.3, (50, 3)).astype(float)  # splits of 50 targets, 3 draws
    incumbent = rng.poisson(0.2, (50, 3)).astype(float)
    test = _per_target(candidate, incumbent, more_is_better=False)
    t = stats.ttest_rel(incumbent.mean(axis=1), candidate.mean(axis=1)).statistic
    assert np.isclose(test.z, t, rtol=1e-12)
    assert np.isclose(test.gain, incumbent.mean() - candidate.mean(), rtol=1e-12)
    # Recall: per-target sums of found components over the targets' component counts.
    components = rng.integers(1, 12, 50).astype(float)
    found_c = np.minimum(components[:, None], rng.binomial(12, 0.9, (50, 3)))
    found_i = np.minimum(components[:, None], rng.binomial(12, 0.95, (50, 3)))
    good = np.ones((int(components.sum()), 3), dtype=bool)
    at = np.zeros(len(good), int)
    recall = paired(
        Counts(found_c, components, good, at), Counts(found_i, components, good, at), True
    )
    assert np.isclose(recall.gain, (found_c.mean(1) - found_i.mean(1)).sum() / components.sum())
    t = stats.ttest_rel(found_c.mean(axis=1), found_i.mean(axis=1)).statistic
    assert np.isclose(recall.z, t, rtol=1e-12)


def test_the_same_sampler_is_refused_about_one_time_in_a_hundred() -> None:
    rng = np.random.default_rng(2)
    # Per-target probabilities of a right count like a served sampler's: most targets
    # always right, some never, a tenth in between.
    p = np.where(rng.random(TARGETS) < 0.1, rng.random(TARGETS), rng.random(TARGETS) < 0.97)
    judgements = 4000
    refused_by_mean = lost = 0
    for _ in range(judgements):
        candidate = (rng.random((TARGETS, DRAWS)) < p[:, None]).astype(float)
        incumbent = (rng.random((TARGETS, DRAWS)) < p[:, None]).astype(float)
        test = _per_target(candidate, incumbent)
        refused_by_mean += test.z < -Z_REFUSE
        lost += bool(test.lost_targets)
    # 1 % of 4000: 40, binomial sd 6.3; the t statistic of 200 targets is near normal.
    assert 15 <= refused_by_mean <= 70
    # The chance of a lost unit, summed over the targets: at most 4^-S each.
    bound = float(np.sum(p**DRAWS * (1 - p) ** DRAWS)) * judgements
    assert lost <= bound + 4 * np.sqrt(bound) + 3
    assert bound <= TARGETS * 4.0**-DRAWS * judgements


def test_a_target_lost_for_good_is_refused_and_a_uniform_loss_is_infinitely_sure() -> None:
    incumbent = np.ones((TARGETS, DRAWS))
    incumbent[:10, 1] = 0.0  # ten targets the incumbent misses once
    candidate = incumbent.copy()
    candidate[37] = 0.0  # target 37 wrong on every draw
    test = _per_target(candidate, incumbent)
    assert test.z > -Z_REFUSE  # one target of 200 is within the spread of the mean
    assert test.lost_targets == [37] and test.worse
    # Lost only where the incumbent was right on every draw: target 3 it missed once.
    candidate = incumbent.copy()
    candidate[3] = 0.0
    assert _per_target(candidate, incumbent).lost_targets == []
    # Worse on every target by the same amount: no spread, z = -inf.
    uniform = _per_target(np.full((TARGETS, DRAWS), 1.0), np.full((TARGETS, DRAWS), 0.0), False)
    assert uniform.z == -np.inf and uniform.worse
    assert _per_target(incumbent, incumbent).z == 0.0
    assert not _per_target(incumbent, incumbent).worse


def test_sets_judged_apart_combine_as_stouffers_z() -> None:
    for z_of_sets in ([-1.77, -1.91], [-1.57, -1.0, 0.4], [2.0]):
        upper_tail = stats.norm.sf(z_of_sets)
        expected = stats.combine_pvalues(upper_tail, method="stouffer").statistic
        assert together(z_of_sets) == pytest.approx(expected, abs=1e-12)
    assert together([-2.0]) == -2.0
    assert together([-1.8, -1.8]) < -Z_REFUSE < -1.8
    with pytest.raises(ValueError, match="at least one"):
        together([])
