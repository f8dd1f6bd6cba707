"""recipe: the ablation's keep rule, applied to hand-made measurements, and the step timer.

A quality option is kept only when every raw error drops by RAW_GAIN at no more than
KEEP_RATE_SLACK of keep rate; a speed option only when it is SPEED_GAIN faster with raw
errors within RAW_SLACK. The step timer times both precisions for the same network.
"""

from __future__ import annotations

from dataclasses import replace

from training.evaluate.recipe import OPTIONS, Measured, better, step_times_ms

BEST = Measured(
    name="best", flags=(), e_p_pct=10.0, e_o_pct=20.0, keep_rate=0.5,
    validation_loss=0.7, wall_time_s=100.0, samples_per_s=1000.0,
)  # fmt: skip
QUALITY = next(o for o in OPTIONS if not o.speed)
SPEED = next(o for o in OPTIONS if o.speed)


def test_a_quality_option_must_lower_every_raw_error_without_costing_keep_rate() -> None:
    assert better(replace(BEST, e_p_pct=9.4, e_o_pct=18.9), BEST, QUALITY)
    assert not better(replace(BEST, e_p_pct=9.4, e_o_pct=19.5), BEST, QUALITY)  # e_o -2.5 %
    assert not better(replace(BEST, e_p_pct=5.0, e_o_pct=10.0, keep_rate=0.49), BEST, QUALITY)
    position = replace(BEST, e_o_pct=None)
    assert better(replace(position, e_p_pct=9.4), position, QUALITY)  # e_p alone decides


def test_a_speed_option_must_be_faster_at_the_same_quality() -> None:
    assert better(replace(BEST, samples_per_s=1200.0, e_p_pct=10.4), BEST, SPEED)
    assert not better(replace(BEST, samples_per_s=1100.0), BEST, SPEED)  # only 10 % faster
    assert not better(replace(BEST, samples_per_s=2000.0, e_o_pct=21.5), BEST, SPEED)


def test_step_timer_reports_both_precisions() -> None:
    times = step_times_ms(7, 9, width=16, layers=2, batch=32, rounds=2, steps=2)
    assert set(times) == {"float32", "bf16 autocast"}
    for t in times.values():
        assert 0 < t["best_ms"] <= t["median_ms"]
