"""Phase 1: seeds spread over the samples that reach the target, at least the seed
spacing apart on the joint torus."""

from __future__ import annotations

import numpy as np

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.trace.points import torus_difference


def spread_seeds(q_rad: FloatArray, spacing_rad: float, batch: int = 32) -> FloatArray:
    """A subset (S, n) of q_rad (M, n), greedily at least `spacing_rad` apart on the torus:
    in order, each point not within the spacing of one already chosen is chosen.

    The choice goes `batch` points at a time: the next points not yet covered choose among
    themselves (a small table of which are within the spacing of which), then every point
    within the spacing of a new seed is covered. No KD-tree, a few passes in all.
    """
    within = Spacing(q_rad, spacing_rad)
    remaining = np.arange(len(q_rad))  # (R,) not within the spacing of a chosen seed, in order
    chosen = []
    while len(remaining):
        head = remaining[:batch]  # (K,)
        near = within(head, head)  # (K, K)
        free = np.ones(len(head), dtype=bool)
        picked = []
        for k in range(len(head)):
            if free[k]:
                picked.append(k)
                free &= ~near[k]
        chosen.append(head[picked])
        remaining = remaining[~within(remaining, chosen[-1]).any(axis=1)]
    return q_rad[np.concatenate(chosen)]


class Spacing:
    """Which pairs of configurations are within a distance r on the joint torus.

    The chord between two points' circle embeddings (cos q, sin q), one matrix product for
    a whole table, is never longer than their torus distance d, and when it is at most r
    it is at least ratio x d (each joint's 2 sin(x / 2) >= ratio x over the x it then
    allows): only the pairs between the two bounds need d itself.
    """

    def __init__(self, q_rad: FloatArray, spacing_rad: float) -> None:
        self.q_rad = q_rad  # (M, n)
        self.circle = np.concatenate([np.cos(q_rad), np.sin(q_rad)], axis=1)  # (M, 2n)
        self.r2 = spacing_rad**2
        half = min(spacing_rad / 2.0, 1.0)
        self.sure2 = (half / np.arcsin(half)) ** 2 * self.r2 - 1e-9  # chord^2 below: within

    def __call__(self, rows_a: IntArray, rows_b: IntArray) -> BoolArray:  # (A,), (B,) -> (A, B)
        chord2 = 2.0 * self.q_rad.shape[1] - 2.0 * (self.circle[rows_a] @ self.circle[rows_b].T)
        near = chord2 < self.sure2
        a, b = np.nonzero(~near & (chord2 <= self.r2 + 1e-9))
        if len(a):
            offset = torus_difference(self.q_rad[rows_a[a]], self.q_rad[rows_b[b]])
            near[a, b] = np.einsum("kn,kn->k", offset, offset) <= self.r2
        return near
