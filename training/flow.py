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


@torch.no_grad()
def euler_sample(
    velocity: nn.Module, q_0: torch.Tensor, condition: torch.Tensor, steps: int
) -> torch.Tensor:
    """Integrate dq/dt = v(q, t, x) from t=0 to 1 with explicit Euler; q_0 (B, n) -> q_1 (B, n)."""
    q_t = q_0
    dt = 1.0 / steps
    for k in range(steps):
        t = torch.full((q_0.shape[0], 1), k * dt, dtype=q_0.dtype, device=q_0.device)
        q_t = q_t + dt * velocity(q_t, t, condition)
    return q_t
