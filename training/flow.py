"""Conditional flow matching with the linear (optimal-transport) path.

q_t = (1 - t) q_0 + t q_1, target velocity dq_t = q_1 - q_0, q_0 ~ N(0, I), t ~ p(t):
uniform on [0, 1] (paper) or logit-normal, t = sigmoid(N(mean, std)) (SD3).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

TIME_SAMPLINGS = ("uniform", "logit_normal")


def cfm_loss(
    velocity: nn.Module,
    q_1: torch.Tensor,  # (B, n) data
    condition: torch.Tensor,  # (B, c)
    q_0: torch.Tensor,  # (B, n) prior noise
    t: torch.Tensor,  # (B, 1)
) -> torch.Tensor:
    """Mean squared error between v(q_t, t, x) and the path's velocity q_1 - q_0, in float32
    also when v runs under bf16 autocast."""
    q_t = (1 - t) * q_0 + t * q_1
    dq_t = q_1 - q_0
    return torch.mean((velocity(q_t, t, condition).float() - dq_t) ** 2)


@dataclass(frozen=True)
class TimeSampling:
    """The distribution of flow times t in training; ValueError lists the valid kinds."""

    kind: str = "uniform"
    logit_mean: float = 0.0  # logit_normal only: the median of t is sigmoid(logit_mean)
    logit_std: float = 1.0

    def __post_init__(self) -> None:
        if self.kind not in TIME_SAMPLINGS:
            raise ValueError(
                f"unknown time sampling {self.kind!r}; choose from {list(TIME_SAMPLINGS)}"
            )
        if not self.logit_std > 0:
            raise ValueError(f"time_logit_std must be positive, got {self.logit_std}")

    def sample(self, count: int, generator: torch.Generator) -> torch.Tensor:
        """t (count, 1) float32; uniform draws exactly what the paper's loop drew."""
        if self.kind == "uniform":
            return torch.rand(count, 1, generator=generator)
        z = torch.randn(count, 1, generator=generator)  # (count, 1)
        return torch.sigmoid(self.logit_mean + self.logit_std * z)
