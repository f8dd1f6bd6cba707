"""wire: the models shared with the client name the pipeline's timed spans, in its order.

`service/wire.py` spells out `TimedSpan` (the keys of `timings_ms`) so that it needs no
numpy; this checks it against the pipeline's own `TIMED_SPANS`.
"""

from __future__ import annotations

from typing import get_args

from service import wire
from service.pipeline.types import TIMED_SPANS


def test_timed_spans_are_the_pipelines() -> None:
    assert get_args(wire.TimedSpan) == TIMED_SPANS
