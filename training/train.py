"""Train the flow, keep the best-validation checkpoint, export it: the `smm-train` CLI.

    smm-train --robot planar3r --task position --samples 1000000 --epochs 60

writes models/<robot>-<task>/ (flow.onnx, kinematics.onnx, manifest.json); the
checkpoint and the training log go to runs/<robot>-<task>/ (not in git).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import shlex
import shutil
import sys
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path

import torch
from tqdm import tqdm

from service.config import REPO_MODELS_DIR
from training.config import TrainConfig, preset
from training.data import FlowData, build_flow_data
from training.flow import cfm_loss
from training.kinematics import ForwardKinematics, joint_spec, load_chain
from training.model import VelocityField
from training.robots import robot_spec


@dataclass(frozen=True)
class TrainResult:
    model: VelocityField  # best-validation weights
    best_validation_loss: float
    best_epoch: int
    history: list[dict[str, float]]
    wall_time_s: float


def build_model(config: TrainConfig, data: FlowData) -> VelocityField:
    """The velocity field of `config`'s architecture for `data`'s joint and condition sizes."""
    return VelocityField(
        joint_dim=data.q_1.shape[1],
        condition_dim=data.condition.shape[1],
        hidden_width=config.hidden_width,
        hidden_layers=config.hidden_layers,
        time_embedding_dim=config.time_embedding_dim,
    )


def split(
    data: FlowData, fraction: float, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Shuffled indices: (train (N_train,), validation (N_val,))."""
    order = torch.randperm(data.q_1.shape[0], generator=generator)
    num_val = max(1, round(fraction * len(order)))
    return order[num_val:], order[:num_val]


def train_one_epoch(
    model: VelocityField,
    q_1: torch.Tensor,
    condition: torch.Tensor,
    optimizer: torch.optim.Optimizer,
    scheduler: torch.optim.lr_scheduler.LRScheduler,
    batch_size: int,
    generator: torch.Generator,
    progress: tqdm,
) -> float:
    """One pass over (q_1, condition) in shuffled batches; returns the mean training loss."""
    model.train()
    device = q_1.device
    order = torch.randperm(q_1.shape[0], generator=generator).to(device)
    total, batches = 0.0, 0
    for start in range(0, len(order), batch_size):
        index = order[start : start + batch_size]
        q_0 = torch.randn(len(index), q_1.shape[1], generator=generator).to(device)
        t = torch.rand(len(index), 1, generator=generator).to(device)
        loss = cfm_loss(model, q_1[index], condition[index], q_0, t)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        scheduler.step()
        total += loss.item()
        batches += 1
        progress.update(1)
    return total / batches


@torch.no_grad()
def evaluate(
    model: VelocityField,
    q_1: torch.Tensor,
    condition: torch.Tensor,
    q_0: torch.Tensor,
    t: torch.Tensor,
    batch_size: int = 65_536,
) -> float:
    """Validation CFM loss with fixed noise and times, so epochs compare like for like."""
    model.eval()
    total = 0.0
    for start in range(0, q_1.shape[0], batch_size):
        s = slice(start, start + batch_size)
        total += float(cfm_loss(model, q_1[s], condition[s], q_0[s], t[s])) * len(q_1[s])
    return total / q_1.shape[0]


def train(config: TrainConfig, data: FlowData) -> TrainResult:
    torch.manual_seed(config.seed)
    generator = torch.Generator().manual_seed(config.seed)
    device = torch.device(config.device)
    train_index, val_index = split(data, config.validation_fraction, generator)
    q_train = data.q_1[train_index].to(device)
    c_train = data.condition[train_index].to(device)
    q_val = data.q_1[val_index].to(device)
    c_val = data.condition[val_index].to(device)
    q_0_val = torch.randn(q_val.shape, generator=generator).to(device)
    t_val = torch.rand(q_val.shape[0], 1, generator=generator).to(device)

    model = build_model(config, data).to(device)
    optimizer = torch.optim.AdamW(
        model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    steps_per_epoch = math.ceil(q_train.shape[0] / config.batch_size)
    scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
        optimizer, T_max=config.epochs * steps_per_epoch
    )
    best_loss, best_epoch, best_state = math.inf, -1, copy.deepcopy(model.state_dict())
    history: list[dict[str, float]] = []
    start = time.perf_counter()
    with tqdm(total=config.epochs * steps_per_epoch, unit="batch", mininterval=2.0) as progress:
        for epoch in range(config.epochs):
            train_loss = train_one_epoch(
                model,
                q_train,
                c_train,
                optimizer,
                scheduler,
                config.batch_size,
                generator,
                progress,
            )
            val_loss = evaluate(model, q_val, c_val, q_0_val, t_val)
            history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss})
            if val_loss < best_loss:
                best_loss, best_epoch = val_loss, epoch
                best_state = copy.deepcopy(model.state_dict())
            progress.set_postfix(epoch=epoch, train=f"{train_loss:.4f}", val=f"{val_loss:.4f}")
    model.load_state_dict(best_state)
    return TrainResult(
        model=model.cpu().eval(),
        best_validation_loss=best_loss,
        best_epoch=best_epoch,
        history=history,
        wall_time_s=time.perf_counter() - start,
    )


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
    parser.add_argument(
        "--from-checkpoint",
        type=Path,
        default=None,
        help="skip training: re-export a best.pt written by an earlier run (its budget and "
        "provenance are kept) with the current serving defaults, and re-measure quality",
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


def load_checkpoint(path: Path, data: FlowData) -> tuple[TrainConfig, TrainResult, str]:
    checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    config = TrainConfig(**checkpoint["config"])
    model = build_model(config, data)
    model.load_state_dict(checkpoint["state_dict"])
    result = TrainResult(
        model=model.eval(),
        best_validation_loss=checkpoint["best_validation_loss"],
        best_epoch=checkpoint["best_epoch"],
        history=[],
        wall_time_s=checkpoint["wall_time_s"],
    )
    return config, result, checkpoint["command"]


def main(argv: list[str] | None = None) -> None:
    from training.export import export_model  # torch.onnx is slow to import; only here

    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    config = config_from_args(args)
    if args.from_checkpoint is not None:
        # The data (and so the normalisation) follows from the checkpoint's own config.
        config = TrainConfig(**torch.load(args.from_checkpoint, weights_only=False)["config"])
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
    if args.from_checkpoint is not None:
        config, result, command = load_checkpoint(args.from_checkpoint, data)
    else:
        print(f"[{model_id}] training {config.epochs} epochs on {config.device}")
        result = train(config, data)
        command = shlex.join(["smm-train", *argv])
        run_dir = args.runs_dir / model_id
        run_dir.mkdir(parents=True, exist_ok=True)
        torch.save(
            {
                "state_dict": result.model.state_dict(),
                "best_validation_loss": result.best_validation_loss,
                "best_epoch": result.best_epoch,
                "wall_time_s": result.wall_time_s,
                "config": config.as_dict(),
                "command": command,
            },
            run_dir / "best.pt",
        )
        (run_dir / "history.json").write_text(json.dumps(result.history, indent=1))
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
