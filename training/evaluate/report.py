"""Evaluate a model against ground truth, beside the paper's baselines; write JSON + Markdown.

Targets: the FK of configurations uniform in the joint limits (fixed seed). Ground truth:
the planar closed form, the iiwa14 S-R-S IK (pose: exact components; position: dense
exact points of the 4-D SMM with their components). Methods, each with the same number
of samples per target:

- FM: the flow's raw samples (default sampler), all of them;
- FM + DLS: the service's pipeline with its defaults (what a client gets);
- random-restart DLS: pytorch-kinematics PseudoInverseIK from uniform restarts, judged
  by the same acceptance and grouped by the same connect stage (its time includes both);
- ODE (1-D SMMs only): the paper's null-space RK5 trace from the generating configuration;
- Fourier (planar 3R only): the paper's third method, realtime-smm's per-cluster Fourier
  regressors (baselines/fourier.py; trained once by its --train into runs/), its raw
  prediction and the same points after the service's DLS correction and acceptance. Where
  it cannot run (another robot, realtime-smm not installed, no trained model) the report
  says so under "skipped".

Every configuration FM + DLS returns is also checked by the robot's reference FK, which
shares no code with the service (`reference_fk`: the planar closed form, the DH tables);
the sample accounting of every answer (sampled = accepted + rejected) is the pipeline's
own, checked by the service's tests.

    smm-train report --model iiwa14-pose --targets 200   # -> docs/reports/
    smm-train report --model iiwa14-pose --targets 200 \
        --candidate '{"sampler": {"flow": "reflow", "steps": 2}}' --out /tmp/candidate
    smm-train report --table-2   # the paper's Table 2 beside ours
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.joint_space import JointLimits
from training.evaluate.baselines.fourier import (
    FOURIER,
    FOURIER_DLS,
    RUN_DIR,
    FourierModel,
    FourierUnavailable,
    fourier_targets,
    load_for,
)
from training.evaluate.judge import candidate_defaults
from training.evaluate.methods import (
    MethodTarget,
    flow_target,
    ode_target,
    raw_samples_target,
    restart_target,
)
from training.evaluate.metrics import (
    COUNT_RIGHT_DEFINITION,
    missed_components,
    summarise,
    wrong_count_targets,
)
from training.evaluate.reference_fk import reference_fk_check
from training.evaluate.rendering import markdown, table_2
from training.evaluate.served import serving
from training.evaluate.targets import near_boundary, uniform_configurations
from training.evaluate.truth import ground_truth
from training.kinematics import load_chain
from training.machine import Machine
from training.robots import robot_spec

REPORTS_DIR = Path(__file__).resolve().parents[2] / "docs" / "reports"


RESTARTS = "random-restart DLS"


def build_report(
    model: ServedModel, num_targets: int, seed: int, num_samples: int, fourier_dir: Path = RUN_DIR
) -> dict[str, object]:
    """Every method on `num_targets` held-out targets (seed), measured against ground truth
    (the Fourier baseline from the model trained in `fourier_dir`, where it runs)."""
    machine = Machine.now()
    manifest = model.manifest
    limits = JointLimits.of(manifest.joints)
    q_targets = uniform_configurations(limits, num_targets, seed)
    robot = robot_spec(manifest.robot)
    chain = load_chain(REPO_MODELS_DIR / robot.urdf, robot.end_effector_link, robot.base_link)
    one_dimensional = manifest.joints.count - manifest.task.dimension == 1
    truths = [ground_truth(model, q, seed + i) for i, q in enumerate(q_targets)]
    flow_target(model, q_targets[0], 10, seed=0)  # warm-up: onnxruntime's first-call cost
    methods: dict[str, list[MethodTarget]] = {"FM + DLS": [], "FM": []}
    skipped: dict[str, str] = {}
    restarts = manifest.task.tool_axis is None
    if restarts:
        methods[RESTARTS] = []
    else:
        skipped[RESTARTS] = (
            "pytorch-kinematics' PseudoInverseIK constrains a whole pose or a position, not "
            "a tool axis with its rotation free"
        )
    if one_dimensional:
        methods["ODE"] = []
    fourier: FourierModel | None = None
    try:
        fourier = load_for(manifest, fourier_dir)
    except FourierUnavailable as why:
        skipped[FOURIER] = str(why)
    if fourier is not None:
        methods[FOURIER], methods[FOURIER_DLS] = [], []
        fourier_targets(model, fourier, q_targets[0], 10)  # warm-up, like the flow's
    for i, q in enumerate(q_targets):
        answer = flow_target(model, q, num_samples, seed=i)
        methods["FM + DLS"].append(answer)
        methods["FM"].append(raw_samples_target(answer))
        if restarts:
            methods[RESTARTS].append(restart_target(model, chain, q, num_samples, seed=i))
        if one_dimensional:
            methods["ODE"].append(ode_target(model, q))
        if fourier is not None:
            raw, corrected = fourier_targets(model, fourier, q, num_samples)
            methods[FOURIER].append(raw)
            methods[FOURIER_DLS].append(corrected)
    boundary = near_boundary(model, q_targets)
    report: dict[str, object] = {
        "model": model.reference,
        "machine": machine.ended().as_json(),
        "targets": num_targets,
        "seed": seed,
        "num_samples": num_samples,
        "defaults": manifest.defaults.model_dump(exclude={"reasons"}),
        "methods": {name: summarise(model, answers, truths) for name, answers in methods.items()},
        "component_size": "arc length (rad)" if one_dimensional else "share of the fibre",
        "count_right_definition": COUNT_RIGHT_DEFINITION,
        "near_boundary": {
            "targets": int(boundary.sum()),
            "indices": np.flatnonzero(boundary).tolist(),
            "FM + DLS": summarise(
                model,
                [a for a, b in zip(methods["FM + DLS"], boundary, strict=True) if b],
                [t for t, b in zip(truths, boundary, strict=True) if b],
            ),
        },
    }
    if fourier is not None:
        report["fourier_training"] = fourier.training
    if skipped:
        report["skipped"] = skipped
    answers = methods["FM + DLS"]
    checked = reference_fk_check(model, q_targets, answers)
    if checked is not None:
        report["reference_fk"] = asdict(checked)
    if truths[0].size is not None:
        report["missed_component_targets"] = missed_components(answers, truths)
    if answers[0].labels is not None:
        report["wrong_count_targets"] = wrong_count_targets(answers, truths)
    return report


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train report`."""
    parser.add_argument("--model", help="a model id under models/, e.g. iiwa14-pose")
    parser.add_argument("--targets", type=int, default=200)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--num-samples", type=int, default=1000)
    parser.add_argument("--out", type=Path, default=REPORTS_DIR)
    parser.add_argument(
        "--candidate",
        help="a JSON object: the served defaults so changed answer (smm-train judge's "
        "--candidate), to see a candidate under the report's protocol; write it elsewhere "
        "than the committed reports (--out)",
    )
    parser.add_argument(
        "--table-2", action="store_true", help="print Table 2 of every report in --out; no run"
    )
    parser.add_argument(
        "--markdown-only", action="store_true", help="rewrite the .md from the model's .json"
    )


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train report`: evaluate the model and write its report (or Table 2, or the .md)."""
    if args.table_2:
        reports = {p.stem: json.loads(p.read_text()) for p in sorted(args.out.glob("*.json"))}
        print(table_2(reports))
        return
    if args.model is None:
        parser.error("--model is required (or --table-2)")
    if args.markdown_only:
        saved = json.loads((args.out / f"{args.model}.json").read_text())
        (args.out / f"{args.model}.md").write_text(markdown(args.model, saved))
        return
    model = load_model(REPO_MODELS_DIR / args.model, threads=0)
    if args.candidate is not None:
        if args.out.resolve() == REPORTS_DIR:
            parser.error("--candidate: give --out, away from the committed reports")
        try:
            model = serving(model, candidate_defaults(model.manifest.defaults, args.candidate))
        except ValueError as error:
            parser.error(str(error))
    report = build_report(model, args.targets, args.seed, args.num_samples)
    skipped = report.get("skipped")
    if isinstance(skipped, dict):
        for name, why in skipped.items():
            print(f"skipped {name}: {why}", file=sys.stderr)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{args.model}.json").write_text(json.dumps(report, indent=1) + "\n")
    (args.out / f"{args.model}.md").write_text(markdown(args.model, report))
    print(markdown(args.model, report))
