"""deadline: the pipeline stops itself at its next step past the deadline, naming the stage."""

import time

import numpy as np
import pytest

from service.errors import DeadlineExceededError
from service.models.registry import ServedModel
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.run import run
from service.pipeline.sampling import euler_integrate
from service.pipeline.types import Query


def test_check_passes_before_and_raises_after_naming_the_stage() -> None:
    deadline = Deadline.after(0.05)
    deadline.check("sample")
    assert 0 < deadline.remaining_s() <= 0.05
    time.sleep(0.06)
    with pytest.raises(DeadlineExceededError, match=r"deadline of 0\.05 s .* stage 'correct'"):
        deadline.check("correct")
    NO_DEADLINE.check("sample")  # never expires


def test_integration_stops_one_step_after_the_deadline() -> None:
    calls = []

    def slow_field(q_t: np.ndarray, t: np.ndarray, condition: np.ndarray) -> np.ndarray:
        calls.append(t[0, 0])
        time.sleep(0.02)
        return np.zeros_like(q_t)

    q_0 = np.zeros((4, 2), np.float32)
    with pytest.raises(DeadlineExceededError, match="'sample'"):
        euler_integrate(slow_field, q_0, np.zeros((4, 0), np.float32), 100, Deadline.after(0.1))
    # 0.1 s of 0.02 s steps: about 5 evaluations ran, far from the 100 asked for.
    assert 3 <= len(calls) <= 10


def test_an_expired_deadline_stops_a_real_query_before_any_work(planar3r: ServedModel) -> None:
    query = Query.for_model(planar3r.manifest, position_m=[0.5, 0.0], num_samples=100)
    expired = Deadline(budget_s=1.0, expires_at_s=time.monotonic() - 1.0)
    with pytest.raises(DeadlineExceededError, match="'sample'"):
        run(planar3r, query, expired)
    assert run(planar3r, query, Deadline.after(60.0)).counts.sampled == 100
