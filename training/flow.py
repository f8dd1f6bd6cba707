"""Conditional flow matching with the linear (optimal-transport) path.

q_t = (1 - t) q_0 + t q_1, target velocity dq_t = q_1 - q_0, q_0 ~ N(0, I), t ~ U[0, 1].
"""

from __future__ import annotations

import torch
from torch import nn


def cfm_loss(
    velocity: nn.Module,
    q_1: torch.Tensor,  # (B, n) data
    condition: torch.Tensor,  # (B, c)
    q_0: torch.Tensor,  # (B, n) prior noise
    t: torch.Tensor,  # (B, 1)
) -> torch.Tensor:
    """Mean squared error between v(q_t, t, x) and the path's velocity q_1 - q_0."""
    q_t = (1 - t) * q_0 + t * q_1
    dq_t = q_1 - q_0
    return torch.mean((velocity(q_t, t, condition) - dq_t) ** 2)
