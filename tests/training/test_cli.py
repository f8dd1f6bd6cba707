"""smm-train: one command, a subcommand per job.

- `smm-train --help` lists every subcommand with one line each, and nothing else runs.
- Each subcommand has its module's options, no more and no fewer (the lists below are the
  options each job takes, written out here, not read from the code).
- A command line that starts with an option trains: `smm-train --robot ...` is
  `smm-train train --robot ...`, so the commands the bundled manifests record still run.
- An unknown subcommand is refused with the list of the known ones.
- No module under training/ runs as a script: `smm-train` is the one entry point.
"""

from __future__ import annotations

import argparse
import ast
import subprocess
from pathlib import Path

import pytest

from training.cli import SUBCOMMANDS, in_subprocess, main, parser_for, with_subcommand

TRAINING = Path(__file__).resolve().parents[2] / "training"

OPTIONS = {
    "sweep": ["--axes", "--model-dir", "--out", "--seed", "--targets", "--threads", "--write"],
    "collision": [
        "--configurations", "--model", "--models-dir", "--package-dir", "--seed",
        "--spheres-per-body", "--srdf",
    ],
    "quantise": ["--model-dir"],
    "quality": ["--model-dir", "--write"],
    "judge": [
        "--candidate", "--candidate-model-dir", "--candidate-seed-offset", "--draws",
        "--model", "--models-dir", "--near-singular", "--num-samples", "--out", "--seed",
        "--targets", "--threads", "--write",
    ],
    "report": [
        "--candidate", "--markdown-only", "--model", "--num-samples", "--out", "--seed",
        "--table-2", "--targets",
    ],
    "scenes": [
        "--margin-m", "--markdown-only", "--max-obstacles", "--model", "--out", "--seed",
        "--targets",
    ],
    "plots": ["--out", "--targets"],
    "merges": ["--model", "--out", "--targets"],
    "recipe": [
        "--epochs", "--eval-targets", "--out", "--robot", "--samples", "--task", "--work-dir",
    ],
    "baseline-fourier": ["--run-dir", "--train"],
}  # fmt: skip


def options_of(name: str) -> list[str]:
    parser = parser_for(name)
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    sub = commands.choices[name]
    return sorted(o for a in sub._actions for o in a.option_strings if o not in ("-h", "--help"))


def test_the_help_lists_every_subcommand_on_one_line() -> None:
    result = subprocess.run(
        in_subprocess("--help"), capture_output=True, text=True, timeout=60, check=True
    )
    names = [
        "train", "reflow", "sweep", "collision", "quantise", "quality", "judge", "report",
        "scenes", "plots", "merges", "recipe", "baseline-fourier",
    ]  # fmt: skip
    assert [s.name for s in SUBCOMMANDS] == names
    for subcommand in SUBCOMMANDS:
        line = next(line for line in result.stdout.splitlines() if subcommand.summary in line)
        # argparse puts a name longer than its column on the line above its summary
        assert subcommand.name in line or len(subcommand.name) > 14


@pytest.mark.parametrize("name", sorted(OPTIONS))
def test_each_subcommand_takes_its_jobs_options(name: str) -> None:
    assert options_of(name) == OPTIONS[name]


def test_train_and_reflow_take_a_flag_per_setting() -> None:
    train = options_of("train")
    flags = [
        "--robot", "--urdf", "--task", "--samples", "--epochs", "--resume",
        "--from-checkpoint", "--refresh-kinematics", "--models-dir", "--runs-dir",
        "--reflow-steps", "--sweep-targets", "--ema-decay", "--no-fresh-data", "--srdf",
    ]  # fmt: skip
    for flag in flags:
        assert flag in train, flag
    assert "--world-size" not in train  # the launcher's
    reflow = options_of("reflow")
    for flag in ["--model-dir", "--runs-dir", "--resume", "--export-only", "--steps"]:
        assert flag in reflow, flag
    assert "--teacher-steps" in reflow and "--sweep-targets" in reflow


def test_a_command_line_starting_with_an_option_trains() -> None:
    assert with_subcommand(["--robot", "planar3r"]) == ["train", "--robot", "planar3r"]
    assert with_subcommand(["sweep", "--model-dir", "m"]) == ["sweep", "--model-dir", "m"]
    assert with_subcommand(["--help"]) == ["--help"]


def test_an_unknown_subcommand_names_the_known_ones(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["evaluate-everything"])
    refused = capsys.readouterr().err
    assert "invalid choice: 'evaluate-everything'" in refused
    assert "'train', 'reflow', 'sweep'" in refused


def test_no_training_module_runs_as_a_script() -> None:
    scripts = []
    for path in sorted(TRAINING.rglob("*.py")):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.If) and "__name__" in ast.unparse(node.test):
                scripts.append(str(path.relative_to(TRAINING.parent)))
    assert scripts == []
