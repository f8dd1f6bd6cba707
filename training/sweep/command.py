"""`smm-train sweep`: sweep a model's serving defaults, print the table, and with
`--write` write the judged defaults into its manifest. The design: docs/sweep.md.

    smm-train sweep --model-dir models/iiwa14-pose --targets 20 [--out sweep.json]
    smm-train sweep --model-dir models/iiwa14-pose \
        --axes flow_precision_bits,sampler_steps --write   # re-sweep some axes, keep the rest
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from service.manifest import MANIFEST_FILE
from service.models.registry import load_model
from training.defaults import write_defaults
from training.evaluate.judge import JUDGED
from training.sweep.plan import AXES
from training.sweep.search import judged_sweep, sweep_defaults


def _to_stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train sweep`."""
    parser.add_argument("--model-dir", required=True, type=Path)
    parser.add_argument("--targets", type=int, default=20)
    parser.add_argument("--seed", type=int, default=11, help="seed of the held-out targets")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, help="write the sweep table as JSON here")
    parser.add_argument(
        "--axes",
        default=",".join(AXES),
        help=f"comma-separated axes to sweep, the rest kept (default: all of {', '.join(AXES)})",
    )
    parser.add_argument(
        "--write", action="store_true",
        help="write the chosen defaults into the manifest if judged no worse than the "
        "served ones against the exact SMMs (training/evaluate/judge.py), else the first "
        "judged no worse of the defaults as each earlier axis left them, else keep those",
    )  # fmt: skip


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train sweep`: sweep, print the table, and with --write the judged defaults."""
    axes = [axis.strip() for axis in args.axes.split(",") if axis.strip()]
    unknown = [axis for axis in axes if axis not in AXES]
    if unknown:
        parser.error(f"--axes: unknown {unknown}; choose from {list(AXES)}")
    served = load_model(args.model_dir, threads=args.threads)  # as the service loads it
    result = sweep_defaults(
        served, args.targets, args.seed, progress=_to_stderr,
        axes=[axis for axis in AXES if axis in axes],
    )  # fmt: skip
    text = json.dumps(result.as_json(), indent=1)
    if args.out:
        args.out.write_text(text + "\n")
    print(text)
    if args.write:
        # What serves changes only if judged no worse than what serves now.
        defaults = judged_sweep(
            served, args.targets, args.seed, served.manifest.defaults, progress=_to_stderr,
            axes=[axis for axis in AXES if axis in axes], first=result,
        )  # fmt: skip
        write_defaults(args.model_dir, defaults)
        verdict = defaults.reasons.get(JUDGED, "unchanged: nothing to judge")
        print(f"defaults written to {args.model_dir / MANIFEST_FILE}; {verdict}", file=sys.stderr)
