"""loop: the pieces the flow's and the reflow's training loops share.

- An atomic write that fails leaves the previous file as it was and no partial file
  that a later run could mistake for it; one that succeeds replaces it.
- A resume without a checkpoint is refused, naming the path.
- The optimiser's cosine schedule reaches a learning rate of 0 after its steps, and a
  step moves the weights down the loss's gradient.
- The best-so-far keeps the weights of the lowest figure offered, not the latest.
- A checkpoint is due once its interval has passed (at once with an interval of 0), and
  the wall time adds the earlier starts' to this one's.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from training.loop import Best, Optimiser, RunClock, atomic_write, resume_payload


def test_a_failed_atomic_write_keeps_the_previous_file(tmp_path: Path) -> None:
    path = tmp_path / "last.pt"
    path.write_text("previous")

    def fails(partial: Path) -> None:
        partial.write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(path, fails)
    assert path.read_text() == "previous"
    atomic_write(path, lambda partial: partial.write_text("next"))
    assert path.read_text() == "next"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.pt"]


def test_resuming_without_a_checkpoint_is_refused_by_path(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"nothing to resume: .*missing\.pt does not exist"):
        resume_payload(tmp_path / "missing.pt")


def test_the_schedule_ends_at_zero_and_a_step_lowers_the_loss() -> None:
    torch.manual_seed(0)
    model = torch.nn.Linear(3, 1)
    optimiser = Optimiser.cosine_adamw(model, learning_rate=0.1, weight_decay=0.0, total_steps=4)
    x, y = torch.randn(16, 3), torch.randn(16, 1)

    def loss() -> torch.Tensor:
        return torch.mean((model(x) - y) ** 2)

    before = loss().item()
    optimiser.step(loss())
    assert loss().item() < before
    for _ in range(3):
        optimiser.step(loss())
    assert optimiser.learning_rate == pytest.approx(0.0, abs=1e-12)


def test_the_best_so_far_keeps_the_lowest_figures_weights() -> None:
    model = torch.nn.Linear(2, 1)
    best = Best.none_yet(model)
    with torch.no_grad():
        model.weight.fill_(1.0)
    assert best.offer(0.5, 0, model)
    with torch.no_grad():
        model.weight.fill_(2.0)
    assert not best.offer(0.7, 1, model)
    assert (best.value, best.at) == (0.5, 0)
    assert torch.equal(best.state["weight"], torch.ones(1, 2))


def test_a_checkpoint_is_due_after_its_interval_and_wall_time_spans_resumes() -> None:
    assert RunClock(every_minutes=0.0).checkpoint_due()
    clock = RunClock(every_minutes=5.0, before_s=100.0)
    assert not clock.checkpoint_due()
    assert 100.0 <= clock.wall_time_s() < 160.0
