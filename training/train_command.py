"""`smm-train train`: URDF -> data -> flow training -> export, for one robot and task.

    smm-train train --robot planar3r --task position --samples 1000000 --epochs 60
    smm-train train --urdf my_arm.urdf --end-effector tool0 [--base-link base] --task pose

`--robot` trains a robot that has a file models/robots/<robot>.json (`training.robots`);
`--urdf` trains any serial arm: it copies the URDF to models/robots/<name>.urdf and writes
models/robots/<name>.json first (name: `--name`, else the URDF's robot name), so the
same model is then one `smm-train train --robot <name>` away. Either way the command
writes models/<robot>-<task>/ (flow.onnx, kinematics.onnx, chain.json, manifest.json);
the checkpoints and the training history go to runs/<robot>-<task>/ (not in git). A
stopped run continues with the same command and `--resume`; `--from-checkpoint
runs/<id>/best.pt` re-exports a trained flow without training; `--refresh-kinematics`
re-exports only the kinematics (kinematics.onnx, chain.json) of an existing model.

The work after training (the sweep, the reflow, the judge, the quality measurement) follows
the budget, samples x epochs: at training.budget.FULL_BUDGET_SAMPLE_EPOCHS and above it
runs at the defaults of training/config.py, below it in proportion, unless its flag is
given (training/budget.py). Before labelling, the command prints its plan: each stage, what
it does or why it does not run, and a rough estimate of its wall time on this machine.

Several processes train one model under PyTorch's launcher (training/distributed.py):

    torchrun --standalone --nproc-per-node 2 --no-python smm-train train \
        --robot planar3r --task position

Each trains on its shard of the data; rank 0 alone writes the robot files, the run
directory and the export (the sweep and quality measurement, after training).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import shutil
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import torch

from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, JointSpec, Manifest, TaskSpec
from service.pipeline.targets import condition_names
from training.budget import (
    FULL_BUDGET_SAMPLE_EPOCHS,
    SCALED_FIELDS,
    judge_package_missing,
    measure_costs,
    plan_run,
    scaled_config,
)
from training.checkout import git_commit
from training.checkpoint import (
    BEST_FILE,
    HISTORY_FILE,
    BestCheckpoint,
    TrainResult,
    load_best,
    save_best,
)
from training.collision.geometry import mesh_references
from training.config import TrainConfig, preset
from training.data import FlowData, build_flow_data
from training.distributed import Processes, from_environment, process_group
from training.export import export_model, refresh_kinematics
from training.kinematics import ForwardKinematics, joint_spec, load_chain
from training.machine import Machine
from training.reflow import LAST_FILE as REFLOW_LAST_FILE
from training.reflow import ReflowConfig, reflow_command, reflow_model
from training.robots import RobotSpec, register_urdf, robot_file, robot_spec
from training.train import build_model, train
from training.urdf import read_serial_chain, require_redundancy

SUMMARY = "Train, export and measure one SMM model."
# TrainConfig fields that are not flags: the robot and task have their own, and the number
# of processes is the launcher's (torchrun --nproc-per-node).
NOT_FLAGS = ("robot", "task", "world_size")
# The work after training, scaled to the budget unless its flag is given (training/budget.py).
SCALED_HELP = {
    "reflow_steps": "optimiser steps of the reflow after export (0: no reflow)",
    "reflow_pairs": "teacher pairs of the reflow",
    "sweep_targets": "held-out targets of the sweep that chooses the serving defaults "
    "(0: no sweep, the starting defaults serve)",
    "judge_targets": "report targets on which a reflowed sampler is judged against the "
    "exact SMMs (robots with an exact reference)",
    "eval_targets": "held-out targets of the quality measurement",
}


# The service's setting of the models directory (service/config.py, env prefix SMM_).
MODELS_DIR_VARIABLE = "SMM_MODELS_DIR"


def default_models_dir() -> Path:
    """The directory the service serves: SMM_MODELS_DIR (service/config.py reads the same
    variable) when set, else the repository's models/. Training writes where serving reads."""
    configured = os.environ.get(MODELS_DIR_VARIABLE)
    return Path(configured) if configured else REPO_MODELS_DIR


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train train`: the robot and task, every TrainConfig field, and
    where and how the run goes."""
    robot = parser.add_mutually_exclusive_group(required=True)
    robot.add_argument(
        "--robot", help="a robot with a file models/robots/<name>.json, e.g. planar3r"
    )
    robot.add_argument(
        "--urdf",
        type=Path,
        help="any serial arm's URDF: registered as models/robots/<name>.json first",
    )
    parser.add_argument("--end-effector", help="with --urdf (required): the end-effector link")
    parser.add_argument(
        "--base-link",
        help="with --urdf: the base link, whose frame targets are in "
        "(default: the root of the URDF's tree)",
    )
    parser.add_argument(
        "--name",
        help="with --urdf: the robot's name (default: the URDF's robot name, "
        "lowercased, characters outside [a-z0-9_-] replaced by '_')",
    )
    parser.add_argument(
        "--srdf",
        type=Path,
        help="with --urdf: the robot's SRDF, copied to models/robots/<name>.srdf; its "
        "disable_collisions are the pairs the collision model never checks (without it "
        "they are sampled as MoveIt's setup assistant does)",
    )
    parser.add_argument(
        "--task",
        required=True,
        help="task name: position, pose or axis (a tool axis's direction, its rotation free)",
    )
    _add_config_arguments(parser)
    _add_run_arguments(parser)


def _add_config_arguments(parser: argparse.ArgumentParser) -> None:
    """A flag per TrainConfig field but NOT_FLAGS (unset: the preset's, or the budget's)."""
    defaults = TrainConfig()
    for f in fields(TrainConfig):
        if f.name not in NOT_FLAGS:
            flag = f"--{f.name.replace('_', '-')}"
            kind = type(getattr(defaults, f.name))
            if kind is bool:  # --flag / --no-flag (bool("False") would be True)
                parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=None)
            elif f.name in SCALED_HELP:
                text = (
                    f"{SCALED_HELP[f.name]} (default: {getattr(defaults, f.name):,} from "
                    f"{FULL_BUDGET_SAMPLE_EPOCHS:,} samples x epochs up, scaled down below)"
                )
                parser.add_argument(flag, type=kind, default=None, help=text)
            else:
                parser.add_argument(flag, type=kind, default=None)


def _add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """Where the model and the run go, and how the run starts."""
    parser.add_argument(
        "--models-dir",
        type=Path,
        default=default_models_dir(),
        help="where the model goes: the directory the service serves, SMM_MODELS_DIR when "
        "set (as for smm-serve), else the repository's models/ (default: %(default)s)",
    )
    parser.add_argument(
        "--runs-dir",
        type=Path,
        default=Path("runs"),
        help="checkpoints and training logs, not part of the model (default: %(default)s)",
    )
    start = parser.add_mutually_exclusive_group()
    start.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in runs/<model-id>/last.pt (written after every epoch) with "
        "the same settings; it ends with the weights an uninterrupted run would have",
    )
    start.add_argument(
        "--from-checkpoint",
        type=Path,
        default=None,
        help="skip training: re-export a best.pt written by an earlier run (its budget and "
        "provenance are kept) with the current serving defaults, and re-measure quality",
    )
    start.add_argument(
        "--refresh-kinematics",
        action="store_true",
        help="no training, no checkpoint: re-export kinematics.onnx and chain.json of the "
        "existing models/<robot>-<task>/ from its URDF (parity checked against "
        "pytorch-kinematics) and rewrite only the manifest's file digests",
    )


def check_args(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """The flags that go with --urdf only, and the one it needs (parser.error otherwise)."""
    if args.urdf is not None and args.end_effector is None:
        parser.error("--urdf needs --end-effector LINK")
    if args.urdf is None:
        given = [
            f for f in ("end_effector", "base_link", "name", "srdf") if getattr(args, f) is not None
        ]
        if given:
            flags = ", ".join(f"--{f.replace('_', '-')}" for f in given)
            parser.error(f"{flags}: only with --urdf (--robot takes them from its robot file)")


def parse_args(argv: list[str]) -> argparse.Namespace:
    """`argv` (the arguments after `smm-train train`) as `smm-train train` reads them."""
    parser = argparse.ArgumentParser(prog="smm-train train", description=SUMMARY)
    add_arguments(parser)
    args = parser.parse_args(argv)
    check_args(args, parser)
    return args


def given_flags(args: argparse.Namespace) -> dict[str, Any]:
    """The TrainConfig fields whose flags were given, and their values."""
    return {
        f.name: getattr(args, f.name)
        for f in fields(TrainConfig)
        if f.name not in NOT_FLAGS and getattr(args, f.name) is not None
    }


def config_from_args(args: argparse.Namespace, robot: str, scale: bool = True) -> TrainConfig:
    """The robot's preset with the flags given; with `scale`, the work after training
    (sweep, reflow, judge, quality) scaled to the budget where no flag sets it
    (training/budget.py)."""
    given = given_flags(args)
    config = replace(preset(robot, args.task, args.models_dir), **given)
    return scaled_config(config, given) if scale else config


def robot_in(models_dir: Path, name: str) -> RobotSpec:
    """The robot file of `name` in `models_dir`; a bundled robot is first copied there, with
    its URDF, SRDF and collision meshes, when `models_dir` is outside the repository and
    lacks them."""
    if models_dir.resolve() != REPO_MODELS_DIR.resolve() and robot_file(name).is_file():
        bundled = robot_spec(name)
        files = [robot_file(name).relative_to(REPO_MODELS_DIR), Path(bundled.urdf)]
        files += [] if bundled.srdf is None else [Path(bundled.srdf)]
        urdf_dir = Path(bundled.urdf).parent
        files += [urdf_dir / m for m in mesh_references(REPO_MODELS_DIR / bundled.urdf)]
        for relative in files:
            if not (models_dir / relative).exists():
                (models_dir / relative).parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(REPO_MODELS_DIR / relative, models_dir / relative)
    return robot_spec(name, models_dir)


def register(args: argparse.Namespace) -> str:
    """The robot's name: `--robot`, or the robot `--urdf` was registered as."""
    if args.urdf is None:
        return str(args.robot)
    robot = register_urdf(
        args.urdf, args.end_effector, args.task, args.models_dir, args.base_link, args.name,
        args.srdf,
    )  # fmt: skip
    print(
        f"[{robot.name}] robot file {robot_file(robot.name, args.models_dir)}: chain "
        f"{robot.base_link} -> {robot.end_effector_link}, tasks {sorted(robot.tasks)}; "
        f"train it again with smm-train train --robot {robot.name} --task {args.task}"
    )
    return robot.name


def robot_or_error(args: argparse.Namespace) -> RobotSpec | str:
    """The robot to train (registered first with `--urdf`), or why it cannot be trained."""
    try:
        robot = robot_in(args.models_dir, register(args))
        robot.task(args.task)
    except ValueError as error:  # a robot, URDF or task that cannot be trained: no traceback
        return f"smm-train: error: {error}"
    return robot


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train train` with `args`; `args.argv`: the command line from `train` on, which
    the manifest records."""
    check_args(args, parser)
    argv: list[str] = args.argv
    processes = from_environment()
    if processes.distributed and (args.from_checkpoint is not None or args.refresh_kinematics):
        raise SystemExit(
            "smm-train: error: --from-checkpoint and --refresh-kinematics train nothing: run "
            "them as one process (smm-train train, not torchrun)"
        )
    with process_group(processes, args.device or TrainConfig().device):
        trained = train_or_load(args, argv, processes)
    if trained is not None and processes.is_main:  # the other processes are done
        export(trained)
        if trained.config.reflow_steps > 0:
            reflow(trained, args.runs_dir, args.resume)


def reflow(trained: Trained, runs_dir: Path, resume: bool) -> None:
    """The exported model reflowed for few-step sampling (training/reflow.py); with
    `resume`, a reflow that was stopped continues."""
    config = trained.config
    model_dir = trained.models_dir / f"{trained.robot.name}-{trained.task.name}"
    reflow_config = ReflowConfig(
        pairs=config.reflow_pairs,
        validation_pairs=min(ReflowConfig().validation_pairs, max(1000, config.reflow_pairs // 10)),
        steps=config.reflow_steps,
        batch_size=config.batch_size,
        threads=config.threads or ReflowConfig().threads,
    )
    started = (runs_dir / model_dir.name / "reflow" / REFLOW_LAST_FILE).is_file()
    print(f"[{model_dir.name}] reflow for few-step sampling: {reflow_config}", flush=True)
    manifest = reflow_model(
        model_dir, runs_dir, reflow_config, resume and started,
        reflow_command(model_dir, reflow_config),
    )  # fmt: skip
    print(json.dumps(manifest.model_dump(include={"defaults": {"sampler"}, "quality": True})))


@dataclass(frozen=True)
class Trained:
    """A trained flow and everything its export needs."""

    robot: RobotSpec
    task: TaskSpec
    joints: JointSpec
    fk: ForwardKinematics
    data: FlowData
    config: TrainConfig
    result: TrainResult
    command: str
    models_dir: Path
    training_commit: str
    code_commit: str
    training_processor: dict[str, object] | None  # None: a best.pt from before it was kept


def train_or_load(
    args: argparse.Namespace, argv: list[str], processes: Processes
) -> Trained | None:
    """Train (every process, one shard each), or load `--from-checkpoint`; None after
    `--refresh-kinematics`, which is all it does."""
    models_dir: Path = args.models_dir
    robot = processes.from_main(lambda: robot_or_error(args))  # rank 0 writes its files
    if isinstance(robot, str):
        raise SystemExit(robot)
    if args.refresh_kinematics:
        model_dir = models_dir / f"{robot.name}-{robot.task(args.task).name}"
        manifest = refresh_kinematics(model_dir, models_dir)
        print(f"[{manifest.model_id}] kinematics refreshed: {json.dumps(manifest.files, indent=1)}")
        return None
    config = replace(config_from_args(args, robot.name), world_size=processes.world_size)
    code_commit = git_commit()  # the code this run imported, before HEAD can move
    best = None if args.from_checkpoint is None else load_best(args.from_checkpoint)
    if best is not None:
        config = best.config  # the data (and so the normalisation) follows from it
        robot = robot_in(models_dir, config.robot)
    if config.threads:
        torch.set_num_threads(config.threads)
    task = robot.task(config.task)
    model_id = f"{robot.name}-{task.name}"
    urdf_path = models_dir / robot.urdf
    require_redundancy(
        read_serial_chain(urdf_path.read_text(), robot.end_effector_link, robot.base_link), task
    )
    chain = load_chain(urdf_path, robot.end_effector_link, robot.base_link)
    fk = ForwardKinematics(chain)
    joints = joint_spec(chain)

    def say(message: str) -> None:  # once, not once per process
        if processes.is_main:
            print(message, flush=True)

    # Before the hours of training: the judge's exact reference must be importable.
    missing = judge_package_missing(robot.name)
    if missing is not None and config.reflow_steps > 0 and config.sweep_targets > 0:
        raise SystemExit(
            f"smm-train: error: {missing}; or train without the reflow (--reflow-steps 0), "
            "which the judge is for"
        )
    if processes.is_main:
        costs = measure_costs(config, joints.count, len(condition_names(task)))
        plan = plan_run(
            config, task, costs, trains=best is None,
            given=set(given_flags(args)) if best is None else set(SCALED_FIELDS),
            full=config_from_args(args, robot.name, scale=False) if best is None else None,
        )  # fmt: skip
        say("\n".join(f"[{model_id}] {line}" for line in plan.lines()))
    say(f"[{model_id}] labelling {config.samples} configurations with pytorch-kinematics")
    data = build_flow_data(fk, joints, task, config.samples, config.seed)
    training_commit = code_commit
    if best is not None:
        result, command = best.result(build_model(config, data)), best.command
        training_commit = best.git_commit or earlier_training_commit(models_dir / model_id, best)
        processor = best.processor
    else:
        run_dir = args.runs_dir / model_id
        processes_note = f" in {processes.world_size} processes" if processes.distributed else ""
        say(f"[{model_id}] training {config.epochs} epochs on {config.device}{processes_note}")
        result = train(config, data, run_dir=run_dir, resume=args.resume, processes=processes)
        processor = here = Machine.now().processor()
        command = shlex.join([*processes.launcher(), *(a for a in argv if a != "--resume")])
        if processes.is_main:
            save_best(run_dir / BEST_FILE, result, config, command, code_commit, here)
            (run_dir / HISTORY_FILE).write_text(json.dumps(result.history, indent=1))
    return Trained(
        robot=robot,
        task=task,
        joints=joints,
        fk=fk,
        data=data,
        config=config,
        result=result,
        command=command,
        models_dir=models_dir,
        training_commit=training_commit,
        code_commit=code_commit,
        training_processor=processor,
    )


def export(trained: Trained) -> None:
    """Export, sweep and measure the trained flow into models/<model-id>/."""
    result, robot, task = trained.result, trained.robot, trained.task
    model_id = f"{robot.name}-{task.name}"
    print(
        f"[{model_id}] best validation loss {result.best_validation_loss:.5f} "
        f"at epoch {result.best_epoch}, {result.wall_time_s:.0f} s; exporting"
    )
    manifest = export_model(
        model_dir=trained.models_dir / model_id,
        models_dir=trained.models_dir,
        robot=robot,
        task=task,
        joints=trained.joints,
        fk=trained.fk,
        data=trained.data,
        config=trained.config,
        result=result,
        command=trained.command,
        code_commit=trained.training_commit,
        export_commit=trained.code_commit,
        processor=trained.training_processor,
    )
    print(json.dumps(manifest.model_dump(include={"quality"}), indent=1))


def earlier_training_commit(model_dir: Path, best: BestCheckpoint) -> str:
    """For a best.pt written before runs stored their commit: the training commit that the
    model's current manifest records, when that manifest came from the same run (same
    command, best epoch and validation loss); otherwise "unknown"."""
    try:
        record = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes()).training
    except (OSError, ValueError):
        return "unknown"
    same_run = (record.command, record.best_epoch, record.best_validation_loss) == (
        best.command, best.best_epoch, best.best_validation_loss,
    )  # fmt: skip
    return record.git_commit if same_run else "unknown"
