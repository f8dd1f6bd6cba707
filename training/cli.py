"""`smm-train`: URDF -> data -> flow training -> export, for one robot and task.

    smm-train --robot planar3r --task position --samples 1000000 --epochs 60

writes models/<robot>-<task>/ (flow.onnx, kinematics.onnx, chain.json, manifest.json);
the checkpoints and the training history go to runs/<robot>-<task>/ (not in git). A
stopped run continues with the same command and `--resume`; `--from-checkpoint
runs/<id>/best.pt` re-exports a trained flow without training; `--refresh-kinematics`
re-exports only the kinematics (kinematics.onnx, chain.json) of an existing model.
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import sys
from dataclasses import fields, replace
from pathlib import Path

import torch

from service.manifest import REPO_MODELS_DIR
from training.checkpoint import BEST_FILE, HISTORY_FILE, load_best, save_best
from training.config import TrainConfig, preset
from training.data import build_flow_data
from training.export import export_model, refresh_kinematics
from training.kinematics import ForwardKinematics, joint_spec, load_chain
from training.robots import robot_spec
from training.train import build_model, train


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="smm-train", description="Train, export and measure one SMM model."
    )
    parser.add_argument("--robot", required=True, help="robot name, e.g. planar3r")
    parser.add_argument("--task", required=True, help="task name, e.g. position")
    defaults = TrainConfig()
    for f in fields(TrainConfig):
        if f.name not in ("robot", "task"):
            flag = f"--{f.name.replace('_', '-')}"
            parser.add_argument(flag, type=type(getattr(defaults, f.name)), default=None)
    parser.add_argument("--models-dir", type=Path, default=REPO_MODELS_DIR)
    parser.add_argument("--runs-dir", type=Path, default=Path("runs"))
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
    return parser.parse_args(argv)


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    config = preset(args.robot, args.task)
    overrides = {
        f.name: getattr(args, f.name)
        for f in fields(TrainConfig)
        if f.name not in ("robot", "task") and getattr(args, f.name) is not None
    }
    return replace(config, **overrides)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    if args.refresh_kinematics:
        robot = robot_spec(args.robot)
        model_dir = args.models_dir / f"{robot.name}-{robot.task(args.task).name}"
        manifest = refresh_kinematics(model_dir, args.models_dir)
        print(f"[{manifest.model_id}] kinematics refreshed: {json.dumps(manifest.files, indent=1)}")
        return
    config = config_from_args(args)
    best = None if args.from_checkpoint is None else load_best(args.from_checkpoint)
    if best is not None:
        config = best.config  # the data (and so the normalisation) follows from it
    if config.threads:
        torch.set_num_threads(config.threads)
    models_dir: Path = args.models_dir
    robot = robot_spec(config.robot)
    task = robot.task(config.task)
    model_id = f"{robot.name}-{task.name}"
    urdf_path = models_dir / robot.urdf
    if not urdf_path.exists():  # a models dir outside the repo gets its own copy of the URDF
        urdf_path.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(REPO_MODELS_DIR / robot.urdf, urdf_path)
    chain = load_chain(urdf_path, robot.end_effector_link)
    fk = ForwardKinematics(chain)
    joints = joint_spec(chain)

    print(f"[{model_id}] labelling {config.samples} configurations with pytorch-kinematics")
    data = build_flow_data(fk, joints, task, config.samples, config.seed)
    if best is not None:
        result, command = best.result(build_model(config, data)), best.command
    else:
        run_dir = args.runs_dir / model_id
        print(f"[{model_id}] training {config.epochs} epochs on {config.device}")
        result = train(config, data, run_dir=run_dir, resume=args.resume)
        command = shlex.join(["smm-train", *(a for a in argv if a != "--resume")])
        save_best(run_dir / BEST_FILE, result, config, command)
        (run_dir / HISTORY_FILE).write_text(json.dumps(result.history, indent=1))
    print(
        f"[{model_id}] best validation loss {result.best_validation_loss:.5f} "
        f"at epoch {result.best_epoch}, {result.wall_time_s:.0f} s; exporting"
    )
    manifest = export_model(
        model_dir=models_dir / model_id,
        models_dir=models_dir,
        robot=robot,
        task=task,
        joints=joints,
        fk=fk,
        data=data,
        config=config,
        result=result,
        command=command,
    )
    print(json.dumps(manifest.model_dump(include={"quality"}), indent=1))


if __name__ == "__main__":
    main()
