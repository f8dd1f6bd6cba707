"""`smm-train`: every training-side command, one subcommand each.

    smm-train --help                      # the subcommands, one line each
    smm-train train --robot planar3r --task position --samples 1000000 --epochs 60
    smm-train sweep --help                # a subcommand's own options

Each subcommand is a module with `add_arguments(parser)` (its options) and
`run_command(args, parser)` (what it does); only the chosen one is imported, so the help
of one never waits for torch. A command line whose first argument is an option, the form
`smm-train --robot ...` that the bundled manifests record, trains: it is `smm-train train`.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from dataclasses import dataclass

PROG = "smm-train"
TRAIN = "train"


@dataclass(frozen=True)
class Subcommand:
    name: str
    module: str  # has add_arguments(parser) and run_command(args, parser)
    summary: str  # one line, for `smm-train --help`


SUBCOMMANDS: tuple[Subcommand, ...] = (
    Subcommand(TRAIN, "training.train_command", "train, export and measure one SMM model"),
    Subcommand("reflow", "training.reflow", "reflow a trained flow for few-step sampling"),
    Subcommand(
        "sweep", "training.sweep.command", "choose a model's serving defaults by measurement"
    ),
    Subcommand(
        "collision",
        "training.collision.command",
        "rebuild a model's collision.json from its URDF",
    ),
    Subcommand("quantise", "training.quantise", "add the int8 flow network to a model"),
    Subcommand("quality", "training.evaluate.quality", "measure a model's quality block again"),
    Subcommand(
        "judge",
        "training.evaluate.judge",
        "judge a change of serving defaults against the exact SMMs",
    ),
    Subcommand(
        "report",
        "training.evaluate.report",
        "write a bundled model's evaluation report (docs/reports)",
    ),
    Subcommand(
        "scenes",
        "training.evaluate.scenes.report",
        "write a model's random-scene report (docs/reports/scenes)",
    ),
    Subcommand("plots", "training.evaluate.plots", "draw the docs' plots from fresh answers"),
    Subcommand(
        "merges",
        "training.evaluate.merges",
        "walk a report's merges: reference splits or unsettled",
    ),
    Subcommand("recipe", "training.evaluate.recipe", "measure the training options on one model"),
    Subcommand(
        "baseline-fourier",
        "training.evaluate.baselines.fourier",
        "train the paper's Fourier baseline for the reports",
    ),
)
BY_NAME = {subcommand.name: subcommand for subcommand in SUBCOMMANDS}


def with_subcommand(argv: list[str]) -> list[str]:
    """`argv` with `train` in front when it starts with an option other than --help."""
    if argv and argv[0].startswith("-") and argv[0] not in ("-h", "--help"):
        return [TRAIN, *argv]
    return argv


def parser_for(chosen: str | None) -> argparse.ArgumentParser:
    """smm-train's parser: every subcommand listed, the options of `chosen` only (its
    module imported)."""
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="Train, reflow, sweep, judge and evaluate SMM models.",
        epilog=f"'{PROG} COMMAND --help' gives a command's options; '{PROG} --robot ...' "
        f"(no command) is '{PROG} {TRAIN} --robot ...'.",
    )
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for subcommand in SUBCOMMANDS:
        module = importlib.import_module(subcommand.module) if subcommand.name == chosen else None
        description = subcommand.summary if module is None else module.__doc__
        sub = commands.add_parser(
            subcommand.name,
            help=subcommand.summary,
            description=description,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        if module is not None:
            module.add_arguments(sub)
            sub.set_defaults(run_command=module.run_command, parser=sub)
    return parser


def main(argv: list[str] | None = None) -> None:
    argv = with_subcommand(sys.argv[1:] if argv is None else list(argv))
    chosen = argv[0] if argv and argv[0] in BY_NAME else None
    parser = parser_for(chosen)
    args = parser.parse_args(argv)
    args.argv = argv
    args.run_command(args, args.parser)


def in_subprocess(*arguments: str) -> list[str]:
    """The command line that runs `smm-train <arguments>` in a new process of this Python."""
    return [sys.executable, "-c", "from training.cli import main; main()", *arguments]
