"""model and flow: time embedding values, velocity-field shapes and the CFM loss."""

import math

import torch

from training.flow import cfm_loss
from training.model import SinusoidalTimeEmbedding, VelocityField


def test_time_embedding_is_sin_cos_of_geometric_frequencies_1_to_1000() -> None:
    embed = SinusoidalTimeEmbedding(64)
    t = torch.tensor([[0.0], [0.25]])
    out = embed(t)
    assert out.shape == (2, 64)
    frequencies = torch.logspace(0, 3, 32)
    # float32 arguments up to 250 rad: compare at 1e-4.
    torch.testing.assert_close(out[1, :32], torch.sin(0.25 * frequencies), atol=1e-4, rtol=0)
    torch.testing.assert_close(out[1, 32:], torch.cos(0.25 * frequencies), atol=1e-4, rtol=0)
    assert abs(float(embed.frequencies[0, -1]) - 1000.0) < 1e-3


def test_velocity_field_has_the_paper_input_width() -> None:
    field = VelocityField(joint_dim=3, condition_dim=2, hidden_width=256, hidden_layers=4)
    first = field.net[0]
    assert isinstance(first, torch.nn.Linear) and first.in_features == 69  # Table 3, 3R
    assert field(torch.zeros(5, 3), torch.zeros(5, 1), torch.zeros(5, 2)).shape == (5, 3)
    linear = [m for m in field.net if isinstance(m, torch.nn.Linear)]
    assert len(linear) == 5  # 4 hidden layers + output


class ExactField(torch.nn.Module):
    """The exact conditional velocity towards a fixed q_1: (q_1 - q_t) / (1 - t)."""

    def __init__(self, q_1: torch.Tensor) -> None:
        super().__init__()
        self.q_1 = q_1

    def forward(self, q_t: torch.Tensor, t: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        return (self.q_1 - q_t) / (1 - t)


def test_cfm_loss_vanishes_for_the_exact_field() -> None:
    q_1 = torch.tensor([[0.3, -0.7]])
    q_0 = torch.randn(64, 2, generator=torch.Generator().manual_seed(0))
    t = torch.rand(64, 1, generator=torch.Generator().manual_seed(1)) * 0.99
    field = ExactField(q_1)
    assert float(cfm_loss(field, q_1.expand(64, 2), torch.zeros(64, 0), q_0, t)) < 1e-10


def test_cfm_loss_of_zero_field_is_mean_squared_path_velocity() -> None:
    q_1, q_0 = torch.ones(4, 2), torch.zeros(4, 2)
    zero = VelocityField(2, 1, 8, 1)
    for parameter in zero.parameters():
        torch.nn.init.zeros_(parameter)
    with torch.no_grad():
        loss = cfm_loss(zero, q_1, torch.zeros(4, 1), q_0, torch.full((4, 1), 0.5))
    assert math.isclose(loss.item(), 1.0)
