"""Phase 1: seeds spread over the samples that reach the target, at least the seed
spacing apart on the joint torus."""

from __future__ import annotations

from service.pipeline import native
from service.pipeline.arrays import FloatArray


def spread_seeds(q_rad: FloatArray, spacing_rad: float) -> FloatArray:
    """A subset (S, n) of q_rad (M, n), greedily at least `spacing_rad` apart on the torus
    (every joint a circle): in order, each point not within the spacing of one already
    chosen is chosen. Compiled (`native.spread_seeds`): a few hundred samples against a
    few dozen seeds, where a batched numpy choice took 0.35 ms an iiwa14 pose answer."""
    return q_rad[native.spread_seeds(q_rad, spacing_rad)]
