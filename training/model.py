"""The conditional velocity field v_theta(q_t, t, x) of flow matching (seed Table 3)."""

from __future__ import annotations

import math

import torch
from torch import nn


class SinusoidalTimeEmbedding(nn.Module):
    """t (B, 1) -> [sin(f t), cos(f t)] (B, dim), dim/2 frequencies f geometric in 1..1000."""

    frequencies: torch.Tensor  # (1, dim/2)

    def __init__(self, dim: int = 64, min_frequency: float = 1.0, max_frequency: float = 1000.0):
        super().__init__()
        if dim % 2:
            raise ValueError(f"time embedding dim must be even, got {dim}")
        frequencies = torch.exp(
            torch.linspace(math.log(min_frequency), math.log(max_frequency), dim // 2)
        )
        self.register_buffer("frequencies", frequencies[None, :])  # (1, dim/2)

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        angle = t * self.frequencies  # (B, dim/2)
        return torch.cat([torch.sin(angle), torch.cos(angle)], dim=-1)


class VelocityField(nn.Module):
    """MLP on [q_t (n), embed(t) (64), condition (c)] -> velocity dq_t (n); SiLU activations."""

    def __init__(
        self,
        joint_dim: int,
        condition_dim: int,
        hidden_width: int = 256,
        hidden_layers: int = 4,
        time_embedding_dim: int = 64,
    ) -> None:
        super().__init__()
        self.time_embedding = SinusoidalTimeEmbedding(time_embedding_dim)
        layers: list[nn.Module] = []
        width_in = joint_dim + time_embedding_dim + condition_dim
        for _ in range(hidden_layers):
            layers += [nn.Linear(width_in, hidden_width), nn.SiLU()]
            width_in = hidden_width
        layers.append(nn.Linear(width_in, joint_dim))
        self.net = nn.Sequential(*layers)

    def forward(self, q_t: torch.Tensor, t: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        """q_t (B, n), t (B, 1), condition (B, c) -> dq_t (B, n)."""
        return self.net(torch.cat([q_t, self.time_embedding(t), condition], dim=-1))
