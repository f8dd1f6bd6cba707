"""Figures of the evaluation (PNG into docs/plots/), like the paper's Figs. 3-6 and more.

- pairwise joint projections of the service's answer against the exact SMM, for a planar
  3R target and an iiwa14 pose target: each returned component in its own colour (a
  split shows as two colours on one exact curve, a merge as one colour on two), each
  returned path (r = 1) drawn as a line through its ordered points;
- FK-error histograms before and after correction for the 4-D case (iiwa14 position);
- count-right accuracy against distance from the base (every model; count right as
  `metrics.COUNT_RIGHT_DEFINITION`: the count, and no split or merge where the ground
  truth labels its components).

    smm-train plots --targets 100
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display

import matplotlib.pyplot as plt
import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.arrays import BoolArray, FloatArray
from training.evaluate.methods import MethodTarget, flow_target
from training.evaluate.metrics import component_agreement
from training.evaluate.targets import distance_from_base_m, uniform_configurations
from training.evaluate.truth import ground_truth

PLOTS_DIR = Path(__file__).resolve().parents[2] / "docs" / "plots"


def count_accuracy_by_distance(
    distance_m: np.ndarray, right: np.ndarray, edges_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Fraction of targets with the right count (B,) and targets per bin (B,), by distance."""
    index = np.clip(np.digitize(distance_m, edges_m) - 1, 0, len(edges_m) - 2)
    totals = np.bincount(index, minlength=len(edges_m) - 1)
    hits = np.bincount(index, weights=right.astype(float), minlength=len(edges_m) - 1)
    with np.errstate(invalid="ignore"):
        return hits / totals, totals


def path_segments(q_rad: FloatArray, closed: bool, periodic: BoolArray) -> list[FloatArray]:
    """The ordered path (P, n) as polylines to draw: closed loops come back to their first
    point, and a line breaks where a periodic joint wraps (a step of more than pi)."""
    if closed and len(q_rad) > 1:
        q_rad = np.concatenate([q_rad, q_rad[:1]])
    if len(q_rad) < 2:
        return [q_rad]
    step = np.abs(np.diff(q_rad, axis=0))  # (P - 1, n)
    wraps = np.flatnonzero(np.any(periodic & (step > np.pi), axis=1)) + 1
    return [piece for piece in np.split(q_rad, wraps) if len(piece)]


def component_colours(count: int) -> list[tuple[float, float, float, float]]:
    """A distinct colour per returned component (tab10, then tab20, then a hue wheel)."""
    if count <= 10:
        return [plt.get_cmap("tab10")(i) for i in range(count)]
    if count <= 20:
        return [plt.get_cmap("tab20")(i) for i in range(count)]
    return [plt.get_cmap("hsv")(i / count) for i in range(count)]


def draw_components(
    axis: plt.Axes, answer: MethodTarget, col: int, row: int, periodic: BoolArray
) -> None:
    """The answer's components on one joint pair: samples as dots, paths as lines."""
    count = answer.component_count or 0
    colours = component_colours(count)
    labels = answer.labels if answer.labels is not None else np.zeros(len(answer.returned), int)
    on_path = answer.on_path if answer.on_path is not None else np.zeros(len(labels), bool)
    for index in range(count):
        members = answer.returned[(labels == index) & ~on_path]
        axis.scatter(members[:, col], members[:, row], s=3, color=colours[index],
                     label=f"component {index + 1}" if index < 8 else None)  # fmt: skip
    for index, path in answer.paths:
        for piece in path_segments(path.q_rad[:, [col, row]], path.closed, periodic[[col, row]]):
            axis.plot(piece[:, 0], piece[:, 1], "-", lw=0.9, color=colours[index])


def pairwise_projection(model: ServedModel, q_target: np.ndarray, path: Path) -> None:
    """Lower-triangle grid of joint pairs: exact SMM (grey) and the returned components,
    one colour each (paths as lines for r = 1)."""
    truth = ground_truth(model, q_target, seed=0).points
    answer = flow_target(model, q_target, model.manifest.defaults.num_samples, seed=0)
    limits = model.limits
    n = q_target.shape[0]
    figure, axes = plt.subplots(n - 1, n - 1, figsize=(2.2 * (n - 1), 2.2 * (n - 1)))
    axes = np.atleast_2d(axes)
    for row in range(1, n):
        for col in range(n - 1):
            axis = axes[row - 1, col]
            if col >= row:
                axis.axis("off")
                continue
            axis.scatter(truth[:, col], truth[:, row], s=1, c="0.8", label="exact SMM")
            draw_components(axis, answer, col, row, limits.periodic)
            axis.set_xlabel(f"q{col + 1} (rad)", fontsize=7)
            axis.set_ylabel(f"q{row + 1} (rad)", fontsize=7)
            axis.tick_params(labelsize=6)
    axes[0, 0].legend(fontsize=5, loc="best", markerscale=2)
    paths = " and paths (lines)" if answer.paths else ""
    figure.suptitle(
        f"{model.reference}: {answer.component_count} returned components\n"
        f"one colour each (samples{paths}); the exact SMM in grey",
        fontsize=8,
    )
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def fk_error_histogram(model: ServedModel, q_targets: np.ndarray, path: Path) -> None:
    """log10 position error of raw flow samples and of returned configurations."""
    answers = [flow_target(model, q, model.manifest.defaults.num_samples, seed=i)
               for i, q in enumerate(q_targets)]  # fmt: skip
    raw = np.concatenate([a.raw_position_m for a in answers])
    returned = np.concatenate([a.returned_position_m for a in answers])
    figure, axis = plt.subplots(figsize=(6, 3.2))
    bins = np.linspace(-17, 0, 69).tolist()
    axis.hist(np.log10(np.maximum(raw, 1e-17)), bins=bins, alpha=0.7, label="raw flow samples")
    axis.hist(np.log10(np.maximum(returned, 1e-17)), bins=bins, alpha=0.7,
              label="returned (after DLS, accepted)")  # fmt: skip
    axis.set_xlabel("log10 position error (m)")
    axis.set_ylabel("samples")
    axis.legend(fontsize=8)
    axis.set_title(f"{model.reference}: FK error, {len(q_targets)} targets", fontsize=9)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def count_accuracy_plot(models: list[ServedModel], num_targets: int, path: Path) -> None:
    """Fraction of targets whose count is right (`COUNT_RIGHT_DEFINITION`), by distance."""
    figure, axis = plt.subplots(figsize=(6, 3.2))
    for model in models:
        limits = model.limits
        q_targets = uniform_configurations(limits, num_targets, seed=11)
        right, distance = [], []
        for i, q in enumerate(q_targets):
            truth = ground_truth(model, q, seed=i)
            answer = flow_target(model, q, model.manifest.defaults.num_samples, seed=i)
            agreement = component_agreement(answer, truth)
            right.append(agreement is not None and agreement.right)
            distance.append(distance_from_base_m(model, q[None])[0] / model.manifest.reach_m)
        edges = np.linspace(0.0, max(distance) + 1e-9, 9)
        fraction, totals = count_accuracy_by_distance(np.array(distance), np.array(right), edges)
        centres = (edges[:-1] + edges[1:]) / 2
        axis.plot(centres[totals > 0], fraction[totals > 0], "o-", label=model.reference)
    axis.set_xlabel("distance from the base (shoulder for the iiwa) / reach L")
    axis.set_ylabel("targets with the count right")
    axis.set_ylim(-0.05, 1.05)
    axis.legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train plots`."""
    parser.add_argument("--targets", type=int, default=100)
    parser.add_argument("--out", type=Path, default=PLOTS_DIR)


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train plots`: draw every plot into --out."""
    del parser
    args.out.mkdir(parents=True, exist_ok=True)
    planar = load_model(REPO_MODELS_DIR / "planar3r-position", threads=0)
    pose = load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=0)
    position = load_model(REPO_MODELS_DIR / "iiwa14-position", threads=0)
    pairwise_projection(planar, np.array([0.4, 2.2, 1.1]), args.out / "planar3r-projections.png")
    pairwise_projection(pose, np.array([0.3, 0.6, 0.0, -1.2, 0.0, 0.9, 0.0]),
                        args.out / "iiwa14-pose-projections.png")  # fmt: skip
    limits = position.limits
    q_targets = uniform_configurations(limits, args.targets, seed=12)
    fk_error_histogram(position, q_targets, args.out / "iiwa14-position-fk-error.png")
    count_accuracy_plot(
        [planar, pose, position], args.targets, args.out / "count-accuracy-by-distance.png"
    )
