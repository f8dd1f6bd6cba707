"""What a run shows while it runs: runs/<id>/log.jsonl (a line per epoch) and loss.png.

Both are rewritten at the end of every epoch (cheap next to an epoch), before last.pt, so
a resumed run drops the lines of epochs it redoes and no epoch is logged twice.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from training.loop import atomic_write

LOG_FILE = "log.jsonl"
LOSS_PLOT_FILE = "loss.png"


def read_log(path: Path) -> list[dict[str, float]]:
    """The rows of a log.jsonl; [] when there is none."""
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def write_log(path: Path, rows: Sequence[dict[str, float]]) -> None:
    """Write `rows` as JSON lines, whole or not at all."""
    text = "".join(json.dumps(row) + "\n" for row in rows)
    atomic_write(path, lambda partial: partial.write_text(text))


def plot_losses(path: Path, history: Sequence[dict[str, float]]) -> None:
    """Training and validation loss against epoch, log scale, as a PNG (Agg, no display)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(6, 4), dpi=100)
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    epochs = [row["epoch"] for row in history]
    axes.plot(epochs, [row["train_loss"] for row in history], "o-", label="train")
    axes.plot(epochs, [row["validation_loss"] for row in history], "o-", label="validation")
    axes.set_yscale("log")
    axes.set_xlabel("epoch")
    axes.set_ylabel("CFM loss")
    axes.grid(True, which="both", alpha=0.3)
    axes.legend()
    figure.tight_layout()
    atomic_write(path, lambda partial: figure.savefig(partial, format="png"))
