"""The connect-stage profile (`python -m tools.connect_profile`): per target the stage's
least time over the repeats and the compiled kernels called on the stage's own thread;
with two row threads the two calls set beside the stage (sigma_min over the trace, the
strands' closest approach) are not counted, since they overlap it, and the rest is."""

from __future__ import annotations

from service.manifest import REPO_MODELS_DIR
from service.models.registry import load_model
from tools.connect_profile import profile_connect, summarise
from training.evaluate.targets import uniform_configurations


def test_the_kernels_on_the_stages_own_thread_are_counted() -> None:
    calls = {}
    for threads in (1, 2):
        # iiwa14 pose targets: their traces are long enough to be set aside (rows.py)
        model = load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=threads)
        q_targets = uniform_configurations(model.limits, 3, 11)
        rows = profile_connect(model, q_targets, num_samples=200, repeats=2)
        assert [row["target"] for row in rows] == [0, 1, 2]
        for row in rows:
            assert 0 < row["kernels_ms"] <= row["connect_ms"] and row["components"] >= 1
        summary = summarise(rows)
        assert summary["connect_ms"] <= summary["connect_p95_ms"]
        calls[threads] = [row["kernel_calls"] for row in rows]
    # On one thread the set-aside calls run on the stage's thread and count; on two, not.
    assert [one - two for one, two in zip(calls[1], calls[2], strict=True)] == [2, 2, 2]
