"""model and flow: time embedding values, velocity-field shapes (both architectures, the
adaLN-Zero start, ONNX parity), the CFM loss (float32 under bf16 autocast), time sampling
against the logit-normal's closed-form quantiles, and the weight average against its
formula."""

import math
from pathlib import Path
from statistics import NormalDist

import pytest
import torch
from torch.nn import functional

from training.ema import WeightAverage
from training.export import export_flow
from training.flow import TimeSampling, cfm_loss
from training.model import ResidualAdaLN, SinusoidalTimeEmbedding, VelocityField


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
    assert isinstance(field.net, torch.nn.Sequential)
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


def resmlp(joint_dim: int = 3, condition_dim: int = 2) -> VelocityField:
    return VelocityField(joint_dim, condition_dim, 32, 5, architecture="resmlp_adaln")


def randomise(module: torch.nn.Module, seed: int = 0) -> None:
    """Every parameter of `module` drawn from N(0, 0.3^2), zero-initialised ones included."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for parameter in module.parameters():
            parameter.copy_(0.3 * torch.randn(parameter.shape, generator=generator))


def inputs(batch: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    return (
        torch.randn(batch, 3, generator=generator),
        torch.rand(batch, 1, generator=generator),
        torch.rand(batch, 2, generator=generator) * 2 - 1,
    )


def test_an_unknown_architecture_is_refused_with_the_choices() -> None:
    """The error names the valid architectures."""
    with pytest.raises(ValueError, match=r"'transformer'; choose from \['mlp', 'resmlp_adaln'\]"):
        VelocityField(3, 2, architecture="transformer")


def test_resmlp_adaln_has_the_field_signature_and_about_the_mlp_parameter_count() -> None:
    """(B, n), (B, 1), (B, c) -> (B, n); at the iiwa's 512 x 5 (n 7, pose c 9) it has
    2 blocks and 1.22x the MLP's parameters, at the 3R's 256 x 4 1 block and 1.04x."""
    assert resmlp()(*inputs(5, 0)).shape == (5, 3)

    def count(module: torch.nn.Module) -> int:
        return sum(p.numel() for p in module.parameters())

    for n, c, width, layers, blocks, ratio in [(7, 9, 512, 5, 2, 1.22), (3, 2, 256, 4, 1, 1.04)]:
        mlp = VelocityField(n, c, width, layers)
        residual = VelocityField(n, c, width, layers, architecture="resmlp_adaln")
        assert isinstance(residual.net, ResidualAdaLN) and len(residual.net.blocks) == blocks
        assert count(residual) / count(mlp) == pytest.approx(ratio, abs=0.005)


def test_resmlp_adaln_starts_at_zero_with_blocks_that_ignore_time_and_condition() -> None:
    """adaLN-Zero: the new field is 0 everywhere; with only its output layer changed it is
    output(LN(input(q_t))), the same for every t and condition (the gates keep the blocks
    shut and the final modulation is zero)."""
    field = resmlp()
    q_t, t, condition = inputs(64, 1)
    with torch.no_grad():
        assert torch.equal(field(q_t, t, condition), torch.zeros(64, 3))
        net = field.net
        assert isinstance(net, ResidualAdaLN)
        randomise(net.output)
        expected = net.output(functional.layer_norm(net.input(q_t), (32,), eps=1e-6))
        _, other_t, other_condition = inputs(64, 2)
        torch.testing.assert_close(field(q_t, t, condition), expected)
        torch.testing.assert_close(field(q_t, other_t, other_condition), expected)


def test_resmlp_adaln_exports_to_onnx_with_parity(tmp_path: Path) -> None:
    """export_flow (dynamo, dynamic batch) and its onnxruntime parity check pass for the
    residual field with every weight non-zero, so serving needs no change."""
    field = resmlp()
    randomise(field)
    export_flow(field, tmp_path / "flow.onnx", joint_dim=3, condition_dim=2)
    assert (tmp_path / "flow.onnx").stat().st_size > 0


def test_cfm_loss_stays_float32_under_bf16_autocast() -> None:
    """Under CPU bf16 autocast the linear layers run in bf16 (the field's output is bf16)
    while the loss is float32 and within bf16 rounding of the float32 loss."""
    field = VelocityField(3, 2, 64, 2)
    q_t, t, condition = inputs(256, 3)
    q_1 = torch.rand(256, 3) * 2 - 1
    with torch.no_grad():
        reference = cfm_loss(field, q_1, condition, q_t, t)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        assert field(q_t, t, condition).dtype == torch.bfloat16
        loss = cfm_loss(field, q_1, condition, q_t, t)
    assert loss.dtype == torch.float32
    assert float(loss) == pytest.approx(float(reference), rel=2e-2)


def test_uniform_times_are_the_papers_draws() -> None:
    """`uniform` consumes the generator exactly as torch.rand(B, 1) did before."""
    drawn = TimeSampling("uniform").sample(100, torch.Generator().manual_seed(5))
    assert torch.equal(drawn, torch.rand(100, 1, generator=torch.Generator().manual_seed(5)))


def test_logit_normal_times_have_the_closed_form_quantiles() -> None:
    """t = sigmoid(N(m, s)) lies in (0, 1) and its p-quantile is sigmoid(m + s Phi^-1(p))
    (the median sigmoid(m)), within sampling error of 200k draws."""
    sampling = TimeSampling("logit_normal", logit_mean=0.5, logit_std=0.8)
    t = sampling.sample(200_000, torch.Generator().manual_seed(0)).double()
    assert t.shape == (200_000, 1) and float(t.min()) > 0 and float(t.max()) < 1
    for p in (0.05, 0.25, 0.5, 0.75, 0.95):
        expected = 1 / (1 + math.exp(-(0.5 + 0.8 * NormalDist().inv_cdf(p))))
        assert float(torch.quantile(t, p)) == pytest.approx(expected, abs=0.005)


def test_an_unknown_time_sampling_is_refused_with_the_choices() -> None:
    """The error names the valid time samplings; a non-positive std is refused too."""
    with pytest.raises(ValueError, match=r"'beta'; choose from \['uniform', 'logit_normal'\]"):
        TimeSampling("beta")
    with pytest.raises(ValueError, match="time_logit_std must be positive"):
        TimeSampling("logit_normal", logit_std=0.0)


def test_weight_average_is_the_hand_computed_ema_over_three_steps() -> None:
    """After 3 optimiser steps theta_1..3 from theta_0, the average is
    d^3 theta_0 + (1 - d) (d^2 theta_1 + d theta_2 + theta_3), parameter by parameter."""
    decay = 0.8
    model = VelocityField(3, 2, 8, 1)
    average = WeightAverage(model, decay)
    optimizer = torch.optim.SGD(model.parameters(), lr=0.5)
    snapshots = [[p.detach().double().clone() for p in model.parameters()]]
    for step in range(3):
        optimizer.zero_grad()
        q_1, t, condition = inputs(16, step + 10)
        cfm_loss(model, q_1, condition, torch.flip(q_1, [0]), t).backward()
        optimizer.step()
        average.update(model)
        snapshots.append([p.detach().double().clone() for p in model.parameters()])
    weights = [decay**3, (1 - decay) * decay**2, (1 - decay) * decay, 1 - decay]
    for i, averaged in enumerate(average.model.parameters()):
        expected = sum(w * snapshot[i] for w, snapshot in zip(weights, snapshots, strict=True))
        assert isinstance(expected, torch.Tensor)
        torch.testing.assert_close(averaged.double(), expected, atol=1e-6, rtol=1e-5)
    assert not torch.equal(snapshots[3][0], snapshots[0][0])  # the steps did move the weights
