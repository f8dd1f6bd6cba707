"""An exponential moving average of a model's weights, theta_ema <- d theta_ema + (1 - d) theta.

Updated after every optimiser step from the initial weights on; the average, not the
last iterate, is what gets validated and exported when `ema_decay` is on.
"""

from __future__ import annotations

import copy

import torch
from torch import nn


class WeightAverage:
    """A frozen copy of `model` whose parameters follow the model's by exponential averaging."""

    def __init__(self, model: nn.Module, decay: float) -> None:
        if not 0.0 < decay < 1.0:
            raise ValueError(f"ema_decay must lie in (0, 1) when on, got {decay}")
        self.decay = decay
        self.model = copy.deepcopy(model).eval().requires_grad_(False)

    @torch.no_grad()
    def update(self, model: nn.Module) -> None:
        """theta_ema <- decay theta_ema + (1 - decay) theta; buffers copied as they are."""
        for average, weight in zip(self.model.parameters(), model.parameters(), strict=True):
            average.lerp_(weight, 1.0 - self.decay)  # average + (1 - d) (weight - average)
        for kept, buffer in zip(self.model.buffers(), model.buffers(), strict=True):
            kept.copy_(buffer)
