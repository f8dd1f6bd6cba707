"""`smm-train scenes`: the evaluation's scene section for one model.

    smm-train scenes --model panda-pose --targets 200 [--seed 7] [--max-obstacles 10]
                     [--margin-m 0.0]        # -> docs/reports/scenes/<model>.json, .md

Per target (the FK of a configuration uniform in the limits and free of self-collision
by coal): a random box scene around the arm (boxes.py), the service's answer in it with
self-collision checked (recorder.py), every configuration it returned or called free
checked by coal on the URDF's own geometry (exactness.py), for a pose model the exact
SMM's free pieces found and merged (reference.py, pieces.py), the free space the check
loses, and the pipeline's time four ways (timing.py). The figures over every target are
summary.py's; the Markdown is rendering.py's.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.run import run
from training.evaluate.report import REPORTS_DIR
from training.evaluate.scenes.boxes import (
    DRAWS_PER_BOX,
    MAX_SIDE_M,
    MIN_SIDE_M,
    scene_target,
    target_fields,
)
from training.evaluate.scenes.coal_model import CoalModel
from training.evaluate.scenes.exactness import RECORDED_PER_TARGET
from training.evaluate.scenes.pieces import MATCH_RAD, MIN_PIECE_SHARE, RESOLUTION_RAD
from training.evaluate.scenes.position import FINER_GRID_STEPS, GRID_STEPS, Q7_LAYERS
from training.evaluate.scenes.position import MATCH_RAD as POSITION_MATCH_RAD
from training.evaluate.scenes.rendering import markdown
from training.evaluate.scenes.summary import summary
from training.evaluate.scenes.target import FIBRE_POINTS, evaluate_target
from training.evaluate.scenes.timing import TIMING_OBSTACLES, query_for
from training.machine import Machine

SCENES_DIR = REPORTS_DIR / "scenes"


def build_scenes_report(
    model: ServedModel, num_targets: int, seed: int, max_obstacles: int, margin_m: float
) -> dict[str, object]:
    """The section's report of one model (module docstring)."""
    machine = Machine.now()
    coal = CoalModel.of(model)
    _warm_up(model, coal, seed, max_obstacles, margin_m)
    targets: list[dict[str, Any]] = []
    for index in range(num_targets):
        scene = scene_target(model, coal, seed, index, max_obstacles, margin_m)
        timing = scene_target(model, coal, seed, index, max_obstacles, margin_m, TIMING_OBSTACLES)
        targets.append(evaluate_target(model, coal, scene, timing.obstacles, margin_m))
    return {
        "model": model.reference,
        "task": model.manifest.task.name,
        "redundancy": model.manifest.redundancy,
        "machine": machine.ended().as_json(),
        "targets": num_targets,
        "seed": seed,
        "max_obstacles": max_obstacles,
        "margin_m": margin_m,
        "num_samples": model.manifest.defaults.num_samples,
        "settings": {
            "box_side_m": [MIN_SIDE_M, MAX_SIDE_M],
            "draws_per_box": DRAWS_PER_BOX,
            "timing_obstacles": TIMING_OBSTACLES,
            "recorded_checked_per_target": RECORDED_PER_TARGET,
            "reference_resolution_rad": RESOLUTION_RAD,
            "match_rad": MATCH_RAD,
            "min_piece_share": MIN_PIECE_SHARE,
            "fibre_points_per_target": FIBRE_POINTS,
            "position_grid_steps": GRID_STEPS,
            "position_finer_grid_steps": list(FINER_GRID_STEPS),
            "position_q7_layers": Q7_LAYERS,
            "position_match_rad": POSITION_MATCH_RAD,
        },
        "summary": summary(targets),
        "per_target": targets,
    }


def _warm_up(
    model: ServedModel, coal: CoalModel, seed: int, max_obstacles: int, margin_m: float
) -> None:
    """One untimed answer first: onnxruntime's first call costs more than the rest."""
    scene = scene_target(model, coal, seed + 1, 0, max_obstacles, margin_m)
    target = target_fields(model, scene.q_target_rad)
    run(model, query_for(model, target, scene.obstacles, True, margin_m, 0))


def report_json(report: dict[str, Any]) -> str:
    """The report as JSON: its figures indented, then one line per target (each target's
    replayable request whole on its line)."""
    head = json.dumps({k: v for k, v in report.items() if k != "per_target"}, indent=1)
    rows = ",\n  ".join(json.dumps(t, separators=(",", ":")) for t in report["per_target"])
    return head[: -len("\n}")] + ',\n "per_target": [\n  ' + rows + "\n ]\n}\n"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train scenes`."""
    parser.add_argument("--model", required=True, help="a model id under models/ with geometry")
    parser.add_argument("--targets", type=int, default=200)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--max-obstacles", type=int, default=10)
    parser.add_argument("--margin-m", type=float, default=0.0)
    parser.add_argument("--out", type=Path, default=SCENES_DIR)
    parser.add_argument(
        "--markdown-only", action="store_true", help="rewrite the .md from the model's .json"
    )


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train scenes`: measure the model in random scenes and write its report."""
    if args.markdown_only:
        saved = json.loads((args.out / f"{args.model}.json").read_text())
        (args.out / f"{args.model}.md").write_text(markdown(args.model, saved))
        return
    if args.targets < 1 or args.max_obstacles < 1 or args.margin_m < 0:
        parser.error("--targets and --max-obstacles at least 1, --margin-m at least 0")
    model = load_model(REPO_MODELS_DIR / args.model, threads=0)
    report = build_scenes_report(model, args.targets, args.seed, args.max_obstacles, args.margin_m)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{args.model}.json").write_text(report_json(report))
    (args.out / f"{args.model}.md").write_text(markdown(args.model, report))
    print(markdown(args.model, report))
