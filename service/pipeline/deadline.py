"""A per-request deadline that the pipeline checks between its steps.

Python cannot stop a thread from outside, so the pipeline stops itself: the stages call
`check(stage)` between network evaluations and DLS steps, so a computation (and its slot)
ends at most one step after its deadline has passed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from service.errors import DeadlineExceededError


@dataclass(frozen=True)
class Deadline:
    budget_s: float  # the whole allowance, for the message
    expires_at_s: float  # on the time.monotonic() clock

    @classmethod
    def after(cls, budget_s: float, start_s: float | None = None) -> Deadline:
        """A deadline `budget_s` seconds after `start_s` (default: now), monotonic clock."""
        start_s = time.monotonic() if start_s is None else start_s
        return cls(budget_s=budget_s, expires_at_s=start_s + budget_s)

    def remaining_s(self) -> float:
        return self.expires_at_s - time.monotonic()

    def check(self, stage: str) -> None:
        """Raise DeadlineExceededError naming `stage` once the deadline has passed."""
        if time.monotonic() > self.expires_at_s:
            raise DeadlineExceededError(stage, self.budget_s)


NO_DEADLINE = Deadline(budget_s=math.inf, expires_at_s=math.inf)
