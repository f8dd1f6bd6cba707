"""Which training options earn their place: a cumulative ablation, each change kept only if
the evaluation shows it helps.

Every variant is one `smm-train` run at the same budget (samples x epochs, same seed,
same held-out targets, the model's measured serving defaults, no defaults sweep), so
variants differ only in the option under test. Options are tried in a fixed order on top
of the best recipe so far:

    EMA of the weights -> fresh configurations each epoch -> logit-normal times
    -> residual MLP with adaLN conditioning -> bf16 autocast

Rule (applied mechanically, `better`): a quality option is kept when the raw error over
all samples at the serving sampler (e_p, and e_o for a pose task) drops by at least
RAW_GAIN without the keep rate at the default correction falling by more than
KEEP_RATE_SLACK; bf16 is a speed option: kept when it trains at least SPEED_GAIN faster
(samples per second over the whole run) and its raw errors are within RAW_SLACK of the
float32 run's. A short budget favours what helps early (EMA, a residual net); the report
says so and the long run confirms or not.

    smm-train recipe --robot iiwa14 --task pose --samples 500000 --epochs 8
    # -> docs/reports/training/recipe-iiwa14-pose.{json,md}; runs under runs/recipe/ (not in git),
    #    a variant whose model is already there is not trained again (the job resumes)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from service.manifest import Manifest
from training.cli import in_subprocess
from training.flow import cfm_loss
from training.model import VelocityField

# Beside, not among, the model reports (docs/reports/*.json are read as model reports).
REPORTS_DIR = Path(__file__).resolve().parents[2] / "docs" / "reports" / "training"
RAW_GAIN = 0.05  # a kept quality option lowers raw errors by at least 5 %
KEEP_RATE_SLACK = 0.005  # ... and costs at most half a point of keep rate
SPEED_GAIN = 0.15  # bf16 kept when at least 15 % faster
RAW_SLACK = 0.05  # ... with raw errors within 5 % of float32's


BASELINE = "paper (MLP, uniform t)"


@dataclass(frozen=True)
class Option:
    name: str
    flags: tuple[str, ...]
    speed: bool = False  # judged by throughput at equal quality, not by quality


OPTIONS = (
    Option("EMA 0.999", ("--ema-decay", "0.999")),
    Option("fresh data each epoch", ("--fresh-data",)),
    Option("logit-normal times", ("--time-sampling", "logit_normal")),
    Option("residual MLP, adaLN", ("--architecture", "resmlp_adaln")),
    Option("bf16 autocast", ("--autocast-bf16",), speed=True),
)


@dataclass(frozen=True)
class Measured:
    name: str
    flags: tuple[str, ...]
    e_p_pct: float
    e_o_pct: float | None
    keep_rate: float
    validation_loss: float
    wall_time_s: float
    samples_per_s: float

    def as_dict(self) -> dict[str, object]:
        return {**self.__dict__, "flags": list(self.flags)}


def better(candidate: Measured, best: Measured, option: Option) -> bool:
    """The rule of the module docstring."""
    errors = [(candidate.e_p_pct, best.e_p_pct)]
    if candidate.e_o_pct is not None and best.e_o_pct is not None:
        errors.append((candidate.e_o_pct, best.e_o_pct))
    if option.speed:
        faster = candidate.samples_per_s >= (1 + SPEED_GAIN) * best.samples_per_s
        return faster and all(new <= (1 + RAW_SLACK) * old for new, old in errors)
    lower = all(new <= (1 - RAW_GAIN) * old for new, old in errors)
    return lower and candidate.keep_rate >= best.keep_rate - KEEP_RATE_SLACK


def step_times_ms(
    joint_dim: int,
    condition_dim: int,
    width: int,
    layers: int,
    batch: int,
    rounds: int = 7,
    steps: int = 15,
) -> dict[str, dict[str, float]]:
    """Optimiser-step time of the paper's MLP in float32 and under bf16 autocast, measured
    in interleaved rounds in one process (so both see the same machine load): best and
    median over rounds of the mean step time, in ms."""
    torch.manual_seed(0)
    times: dict[str, list[float]] = {"float32": [], "bf16 autocast": []}
    for _ in range(rounds):
        for name in times:
            model = VelocityField(joint_dim, condition_dim, width, layers)
            optimizer = torch.optim.AdamW(model.parameters(), lr=1e-3)
            q_1, condition = torch.rand(batch, joint_dim), torch.rand(batch, condition_dim)
            q_0, t = torch.randn(batch, joint_dim), torch.rand(batch, 1)
            start = 0.0
            for step in range(steps + 2):  # two warm-up steps
                if step == 2:
                    start = time.perf_counter()
                with torch.autocast("cpu", dtype=torch.bfloat16, enabled=name != "float32"):
                    loss = cfm_loss(model, q_1, condition, q_0, t)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
            times[name].append((time.perf_counter() - start) / steps * 1e3)
    return {
        name: {"best_ms": float(min(v)), "median_ms": float(np.median(v))}
        for name, v in times.items()
    }


def _variant_dir(args: argparse.Namespace, name: str) -> Path:
    return Path(args.work_dir) / name.replace(" ", "_").replace(",", "")


def _run(args: argparse.Namespace, name: str, flags: tuple[str, ...]) -> Measured:
    work = _variant_dir(args, name)
    model_id = f"{args.robot}-{args.task}"
    manifest_path = work / "models" / model_id / "manifest.json"
    if not manifest_path.is_file():
        command = [
            *in_subprocess("train"), "--robot", args.robot, "--task", args.task,
            "--samples", str(args.samples), "--epochs", str(args.epochs),
            "--sweep-targets", "0", "--eval-targets", str(args.eval_targets),
            "--models-dir", str(work / "models"), "--runs-dir", str(work / "runs"),
            *flags,
        ]  # fmt: skip
        resume = work / "runs" / model_id / "last.pt"
        if resume.is_file():
            command.append("--resume")
        print(f"[recipe] {name}: {' '.join(command[2:])}", flush=True)
        subprocess.run(command, check=True)
    manifest = Manifest.model_validate_json(manifest_path.read_text())
    assert manifest.quality is not None
    raw = manifest.quality.raw[0]
    training = manifest.training
    return Measured(
        name=name,
        flags=flags,
        e_p_pct=raw.position_error_pct_reach_mean,
        e_o_pct=raw.orientation_error_pct_mean,
        keep_rate=manifest.quality.keep_rate,
        validation_loss=training.best_validation_loss,
        wall_time_s=training.wall_time_s,
        samples_per_s=training.samples * training.epochs / training.wall_time_s,
    )


def markdown(report: dict[str, object]) -> str:
    rows = report["rows"]
    assert isinstance(rows, list)
    lines = [
        f"# Training recipe ablation: {report['model']}",
        "",
        f"Budget per variant: {report['samples']:,} samples x {report['epochs']} epochs, "
        f"seed 42; quality on {report['eval_targets']} held-out targets x 1000 samples at the "
        f"serving sampler and correction (`smm-train recipe`). Machine: "
        f"{report['machine']}. Each option is tried on top of the best recipe so far and kept "
        "by the rule in training/evaluate/recipe.py.",
        "",
        "| variant | e_p (% of reach) | e_o (% of pi) | keep rate | val loss | samples/s | kept |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        e_o = "-" if row["e_o_pct"] is None else f"{row['e_o_pct']:.2f}"
        lines.append(
            f"| {row['name']} | {row['e_p_pct']:.2f} | {e_o} | {row['keep_rate'] * 100:.1f} % | "
            f"{row['validation_loss']:.4f} | {row['samples_per_s']:,.0f} | {row['kept']} |"
        )
    steps = report.get("step_times_ms")
    if isinstance(steps, dict):
        lines += [
            "",
            "samples/s above are whole runs on a machine other jobs shared; the speed of bf16 "
            "is read from optimiser steps timed in interleaved rounds in one process "
            f"(batch {report['batch_size']}, the paper's MLP): "
            + ", ".join(
                f"{name} {t['best_ms']:.1f} ms best, {t['median_ms']:.1f} ms median"
                for name, t in steps.items()
            )
            + ".",
        ]
    lines += ["", f"Recipe: `{' '.join(report['recipe_flags'])}`"]  # type: ignore[arg-type]
    return "\n".join(lines) + "\n"


def _machine() -> str:
    model = subprocess.run(
        ["sh", "-c", "lscpu | sed -n 's/^Model name: *//p'"], capture_output=True, text=True
    ).stdout.strip()
    return f"{model or 'unknown CPU'}, torch threads default, no GPU"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train recipe`."""
    parser.add_argument("--robot", required=True)
    parser.add_argument("--task", required=True)
    parser.add_argument("--samples", type=int, default=500_000)
    parser.add_argument("--epochs", type=int, default=8)
    parser.add_argument("--eval-targets", type=int, default=50)
    parser.add_argument("--work-dir", type=Path, default=Path("runs/recipe"))
    parser.add_argument("--out", type=Path, default=REPORTS_DIR)


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train recipe`: each option on top of the best recipe so far; the report."""
    del parser
    args.work_dir = args.work_dir / f"{args.robot}-{args.task}"

    best = _run(args, BASELINE, ())
    rows = [{**best.as_dict(), "kept": "baseline"}]
    recipe: tuple[str, ...] = ()
    for option in OPTIONS:
        candidate = _run(args, f"+ {option.name}", (*recipe, *option.flags))
        kept = better(candidate, best, option)
        rows.append({**candidate.as_dict(), "kept": "yes" if kept else "no"})
        if kept:
            best, recipe = candidate, (*recipe, *option.flags)
    baseline_dir = _variant_dir(args, BASELINE)
    manifest = Manifest.model_validate_json(
        (baseline_dir / "models" / f"{args.robot}-{args.task}" / "manifest.json").read_text()
    )
    config = manifest.training.config
    report = {
        "model": f"{args.robot}-{args.task}",
        "batch_size": config["batch_size"],
        "step_times_ms": step_times_ms(
            manifest.joints.count,
            len(manifest.condition.names),
            int(config["hidden_width"]),  # type: ignore[call-overload]
            int(config["hidden_layers"]),  # type: ignore[call-overload]
            int(config["batch_size"]),  # type: ignore[call-overload]
        ),
        "samples": args.samples,
        "epochs": args.epochs,
        "eval_targets": args.eval_targets,
        "machine": _machine(),
        "rows": rows,
        "recipe_flags": list(recipe),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    stem = f"recipe-{args.robot}-{args.task}"
    (args.out / f"{stem}.json").write_text(json.dumps(report, indent=1) + "\n")
    (args.out / f"{stem}.md").write_text(markdown(report))
    print(markdown(report))
