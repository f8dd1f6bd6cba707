"""Few-step sampling: one round of reflow (Liu et al. 2023) on top of a trained flow.

The base flow v maps noise to configurations along curved paths: each Euler step costs a
network evaluation, and one step from noise lands on the conditional mean, which for
several IK branches is no solution. Reflow straightens the paths without changing where
they end:

1. teacher pairs: for conditions x = FK(q), q Sobol-spread over the limits (the base
   training's distribution, normalised by the manifest's own normalisation), and noise
   z ~ N(0, I), integrate the base flow in float32 with `teacher_steps` Euler steps
   (the service's own integrator, envelope included) to q_1 = Phi(z, x);
2. the student, initialised as the base flow, learns the straight line between each pair:
   q_t = (1 - t) z + t q_1, target velocity q_1 - z, at t = 0 for `zero_time_fraction` of
   the pairs (where a one-step sampler evaluates it) and t ~ U(0, 1) otherwise (so two
   or more uniform steps also land);
3. export as reflow.onnx and reflow_int8.onnx beside the base flow, listed in the
   manifest with a `reflow` record of how they were made; the sweep then measures the
   reflowed sampler against the base one and the manifest's defaults say which serves.

Unlike the base flow's independent coupling, the teacher's coupling is deterministic: a
noise z has one endpoint, so the one-step map z -> q_1 is a function the student can
learn, branch by branch; where two branches meet in noise space it must turn sharply,
and samples drawn there land between branches (the correction and acceptance judge them
like any other sample; the sweep measures what is lost).

    smm-train reflow --model-dir models/iiwa14-pose      # --resume continues

The teacher pairs (runs/<model-id>/reflow/pairs.pt) and the training state (last.pt,
written every `checkpoint_minutes`) stay out of git; a stopped run continues with
`--resume` to the same weights, and a finished one re-exports.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import shlex
import time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from service.manifest import (
    CHAIN_FILE,
    FLOW_FILE,
    MANIFEST_FILE,
    REFLOW_FILE,
    REFLOW_INT8_FILE,
    ChainSpec,
    Defaults,
    Manifest,
    RawError,
    ReflowRecord,
    SamplerSpec,
)
from service.models.registry import load_model, sha256_of
from service.pipeline.sampling import euler_integrate
from service.pipeline.types import VelocityField as NumpyVelocityField
from training.checkout import git_commit
from training.checkpoint import LAST_FILE
from training.config import TrainConfig
from training.data import Labeller
from training.evaluate.judge import REPORT_TARGETS
from training.evaluate.quality import PAPER_SAMPLER, same_sampler
from training.export import export_flow, sweep_and_measure
from training.kinematics import ForwardKinematics, load_chain
from training.loop import Best, Optimiser, RunClock, atomic_torch_save, resume_payload
from training.machine import Machine
from training.model import VelocityField
from training.quantise import quantise_flow
from training.run_log import LOG_FILE
from training.staging import staged_copy
from training.sweep import Axis

PAIRS_FILE = "pairs.pt"


@dataclass(frozen=True)
class ReflowConfig:
    """One reflow run; each default says why."""

    # Teacher pairs: half the base training's 2M pairs; the student sees each ~30 times.
    pairs: int = 1_000_000
    # Held out for the validation loss (the one-step endpoint error, below).
    validation_pairs: int = 20_000
    # The teacher's Euler steps and grid power: the base flow's endpoint to within a few
    # mm of its 100-step endpoint (sampling.py: 15.0 mm at 20 steps, p = 1.5, vs 12.4 at
    # 100 uniform steps on the iiwa14 pose), at a third of the 100 steps' cost.
    teacher_steps: int = 32
    teacher_time_power: float = 1.5
    # Optimiser steps of `batch_size` pairs (the base training's batch size by default).
    steps: int = 30_000
    batch_size: int = 1024
    # Fine-tuning: a tenth of the base training's starting rate, cosine to 0.
    learning_rate: float = 1e-4
    weight_decay: float = 1e-5
    # Share of each batch trained at t = 0, the one-step sampler's only evaluation.
    zero_time_fraction: float = 0.5
    seed: int = 20261124
    threads: int = 2
    # bf16 autocast of the linear layers (as the base training on CPUs with bf16 units).
    autocast_bf16: bool = True
    checkpoint_minutes: float = 5.0
    validate_every: int = 1000  # optimiser steps between validations

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass(frozen=True)
class TeacherPairs:
    """Noise, the base flow's endpoint from it, and the condition (normalised, float32)."""

    z: torch.Tensor  # (P, n)
    q_1: torch.Tensor  # (P, n)
    condition: torch.Tensor  # (P, c)


def base_flow(model_dir: Path) -> VelocityField:
    """The trained base flow as a torch module, its weights read from flow.onnx (the
    exporter keeps the state_dict's names), so a committed model reflows on a fresh clone."""
    import onnx
    from onnx import numpy_helper

    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    config = manifest.training.config
    graph = onnx.load(str(model_dir / FLOW_FILE)).graph
    state = {i.name: torch.from_numpy(numpy_helper.to_array(i).copy()) for i in graph.initializer}
    model = VelocityField(
        joint_dim=manifest.joints.count,
        condition_dim=len(manifest.condition.names),
        hidden_width=int(str(config["hidden_width"])),
        hidden_layers=int(str(config["hidden_layers"])),
        time_embedding_dim=int(str(config["time_embedding_dim"])),
        architecture=str(config.get("architecture", "mlp")),
    )
    model.load_state_dict(state, strict=True)
    return model.eval()


def numpy_field(model: VelocityField) -> NumpyVelocityField:
    """`model` as the service's VelocityField protocol: float32 arrays in and out."""

    @torch.no_grad()
    def velocity(q_t: np.ndarray, t: np.ndarray, condition: np.ndarray) -> np.ndarray:
        out = model(torch.from_numpy(q_t), torch.from_numpy(t), torch.from_numpy(condition))
        return out.numpy()

    return velocity


def teacher_pairs(
    model_dir: Path, teacher: VelocityField, config: ReflowConfig, chunk: int = 8192
) -> TeacherPairs:
    """`config.pairs + config.validation_pairs` teacher pairs for the model in `model_dir`."""
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    urdf = model_dir.parent / manifest.urdf.path
    base_link = None  # where the model's chain starts (chain.json's, as refresh_kinematics)
    if CHAIN_FILE in manifest.files:
        base_link = ChainSpec.model_validate_json((model_dir / CHAIN_FILE).read_bytes()).base_link
    fk = ForwardKinematics(load_chain(urdf, manifest.end_effector_link, base_link))
    labeller = Labeller(
        fk=fk,
        joints=manifest.joints,
        task=manifest.task,
        joint_normalisation=manifest.joint_normalisation,
        condition_normalisation=manifest.condition.normalisation,
    )
    total = config.pairs + config.validation_pairs
    condition = labeller(total, config.seed).condition  # (P, c)
    # The Sobol order is spatially structured: shuffle so the validation tail is a fair draw.
    generator = torch.Generator().manual_seed(config.seed)
    condition = condition[torch.randperm(total, generator=generator)]
    z = torch.randn(total, manifest.joints.count, generator=generator)  # (P, n)
    q_1 = torch.empty_like(z)
    velocity = numpy_field(teacher)
    for start in tqdm(range(0, total, chunk), desc="teacher pairs", mininterval=5.0):
        s = slice(start, start + chunk)
        q_1[s] = torch.from_numpy(
            euler_integrate(
                velocity, z[s].numpy(), np.ascontiguousarray(condition[s].numpy()),
                config.teacher_steps, time_power=config.teacher_time_power,
            )
        )  # fmt: skip
    return TeacherPairs(z=z, q_1=q_1, condition=condition)


def reflow_loss(
    student: torch.nn.Module,
    z: torch.Tensor,  # (B, n)
    q_1: torch.Tensor,  # (B, n)
    condition: torch.Tensor,  # (B, c)
    t: torch.Tensor,  # (B, 1)
) -> torch.Tensor:
    """Mean squared error between v(q_t, t, x) and the straight line's velocity q_1 - z."""
    q_t = (1 - t) * z + t * q_1
    return torch.mean((student(q_t, t, condition).float() - (q_1 - z)) ** 2)


def reflow_times(
    count: int, zero_fraction: float, generator: torch.Generator
) -> torch.Tensor:  # (count, 1)
    """t = 0 for round(zero_fraction * count) rows, U(0, 1) for the rest."""
    t = torch.rand(count, 1, generator=generator)
    t[: round(zero_fraction * count)] = 0.0
    return t


@torch.no_grad()
def endpoint_error(
    student: torch.nn.Module, pairs: TeacherPairs, steps: int, batch: int = 8192
) -> float:
    """Mean squared distance (normalised joint units) between the student's `steps`-step
    uniform Euler endpoint and the teacher's, over `pairs`."""
    student.eval()
    total = 0.0
    for start in range(0, pairs.z.shape[0], batch):
        s = slice(start, start + batch)
        q = pairs.z[s].clone()
        for k in range(steps):
            t = torch.full((q.shape[0], 1), k / steps)
            q = q + student(q, t, pairs.condition[s]) / steps
        total += float(((q - pairs.q_1[s]) ** 2).sum(dim=1).sum())
    return total / pairs.z.shape[0]


@dataclass
class ReflowState:
    """last.pt: the run after `step` optimiser steps, enough to continue it exactly."""

    config: dict[str, object]
    step: int
    model: dict[str, torch.Tensor]
    optimizer: dict[str, Any]
    scheduler: dict[str, Any]
    generator: torch.Tensor
    best_error: float
    best_step: int
    best_model: dict[str, torch.Tensor]
    wall_time_s: float
    teacher_wall_time_s: float


def load_reflow_state(path: Path, config: ReflowConfig) -> ReflowState:
    """The run state in `path`; ValueError when there is none, or naming the settings
    that differ from `config`."""
    state = ReflowState(**resume_payload(path))
    if state.config != config.as_dict():
        differing = sorted(k for k, v in config.as_dict().items() if state.config.get(k) != v)
        raise ValueError(
            f"{path} was written with other settings ({', '.join(differing)}); "
            "resume with the same flags, or start afresh without --resume"
        )
    return state


def cached_pairs(
    model_dir: Path, teacher: VelocityField, config: ReflowConfig, run_dir: Path,
    state: ReflowState | None,
) -> tuple[TeacherPairs, float]:  # fmt: skip
    """The teacher pairs of a resumed run's pairs.pt, else new ones written there; and the
    seconds the teacher took (over the run)."""
    pairs_path = run_dir / PAIRS_FILE
    if state is not None and pairs_path.is_file():
        return TeacherPairs(**torch.load(pairs_path, map_location="cpu")), state.teacher_wall_time_s
    started = time.perf_counter()
    pairs = teacher_pairs(model_dir, teacher, config)
    teacher_wall_time_s = time.perf_counter() - started
    torch.save(asdict(pairs), pairs_path)
    return pairs, teacher_wall_time_s


def train_reflow(
    model_dir: Path, run_dir: Path, config: ReflowConfig, resume: bool
) -> tuple[VelocityField, ReflowState]:
    """Pairs (cached in `run_dir`), then the student's training; the best-validation student."""
    torch.manual_seed(config.seed)
    teacher = base_flow(model_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    last_path = run_dir / LAST_FILE
    state = load_reflow_state(last_path, config) if resume else None
    pairs, teacher_wall_time_s = cached_pairs(model_dir, teacher, config, run_dir, state)
    validation = TeacherPairs(*(x[config.pairs :] for x in (pairs.z, pairs.q_1, pairs.condition)))
    student = copy.deepcopy(teacher).train()
    optimiser = Optimiser.cosine_adamw(
        student, config.learning_rate, config.weight_decay, config.steps
    )
    generator = torch.Generator().manual_seed(config.seed + 1)
    if state is None:
        error = endpoint_error(student, validation, steps=1)
        state = ReflowState(
            config=config.as_dict(), step=0, model={}, optimizer={}, scheduler={},
            generator=generator.get_state(), best_error=error, best_step=0,
            best_model=copy.deepcopy(student.state_dict()), wall_time_s=0.0,
            teacher_wall_time_s=teacher_wall_time_s,
        )  # fmt: skip
        print(f"one-step endpoint error of the base flow: {error:.4f}", flush=True)
    else:
        student.load_state_dict(state.model)
        optimiser.load(state.optimizer, state.scheduler)
        generator.set_state(state.generator)
    steps = ReflowSteps(config, student, optimiser, generator, pairs, validation)
    run_steps(steps, state, last_path, run_dir / LOG_FILE)
    student.load_state_dict(state.best_model)
    return student.eval(), state


@dataclass(frozen=True)
class ReflowSteps:
    """What the student's optimiser steps run on: the training pairs are the first
    `config.pairs` of `pairs`, `validation` the rest."""

    config: ReflowConfig
    student: VelocityField
    optimiser: Optimiser
    generator: torch.Generator  # the batches' rows and times
    pairs: TeacherPairs
    validation: TeacherPairs

    def step(self) -> float:
        """One optimiser step on a batch drawn from the training pairs; its loss."""
        config = self.config
        self.student.train()
        index = torch.randint(0, config.pairs, (config.batch_size,), generator=self.generator)
        t = reflow_times(config.batch_size, config.zero_time_fraction, self.generator)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=config.autocast_bf16):
            loss = reflow_loss(
                self.student,
                self.pairs.z[index],
                self.pairs.q_1[index],
                self.pairs.condition[index],
                t,
            )
        self.optimiser.step(loss)
        return loss.item()


def run_steps(steps: ReflowSteps, state: ReflowState, last_path: Path, log_path: Path) -> None:
    """The optimiser steps from `state.step` to `config.steps`: validated every
    `validate_every` (and at the last), the best kept, last.pt written when due and at the end."""
    config, student = steps.config, steps.student
    best = Best(state.best_error, state.best_step, state.best_model)
    clock = RunClock(config.checkpoint_minutes, before_s=state.wall_time_s)

    def checkpoint() -> None:
        state.model = student.state_dict()
        state.optimizer = steps.optimiser.optimizer.state_dict()
        state.scheduler = steps.optimiser.scheduler.state_dict()
        state.generator = steps.generator.get_state()
        state.best_error, state.best_step, state.best_model = best.value, best.at, best.state
        state.wall_time_s = clock.wall_time_s()
        atomic_torch_save({f.name: getattr(state, f.name) for f in fields(ReflowState)}, last_path)
        clock.saved()

    with (
        log_path.open("a") as log,
        tqdm(total=config.steps, initial=state.step, unit="step", mininterval=5.0) as progress,
    ):
        while state.step < config.steps:
            loss = steps.step()
            state.step += 1
            progress.update(1)
            if state.step % config.validate_every == 0 or state.step == config.steps:
                error = endpoint_error(student, steps.validation, steps=1)
                row = {
                    "step": state.step,
                    "train_loss": loss,
                    "one_step_error": error,
                    "wall_time_s": clock.wall_time_s(),
                }
                log.write(json.dumps(row) + "\n")
                log.flush()
                progress.set_postfix(loss=f"{loss:.4f}", one_step=f"{error:.4f}")
                best.offer(error, state.step, student)
            if clock.checkpoint_due():
                checkpoint()
    checkpoint()


def base_sampler(manifest: Manifest) -> SamplerSpec | None:
    """The base flow's sampler the model serves, or served before an earlier reflow."""
    if manifest.defaults.sampler.flow == "base":
        return manifest.defaults.sampler
    return None if manifest.reflow is None else manifest.reflow.base_sampler


def paper_row(manifest: Manifest, targets: int, samples: int) -> RawError | None:
    """The paper sampler's raw errors the manifest already holds for these targets and
    samples: the base flow's, which the reflow leaves as they were (100 float32 steps
    of an iiwa net on 200 targets cost ~7 min to measure again)."""
    quality = manifest.quality
    if quality is None or (quality.held_out_targets, quality.samples_per_target) != (
        targets, samples,
    ):  # fmt: skip
        return None
    for row in quality.raw:
        if same_sampler(row, PAPER_SAMPLER):
            return row
    return None


def export_reflow(
    model_dir: Path, student: VelocityField | None, record: ReflowRecord, threads: int,
    sweep_targets: int, sweep_seed: int, eval_targets: int, eval_samples_per_target: int,
    eval_seed: int, judge_targets: int = REPORT_TARGETS,
) -> Manifest:  # fmt: skip
    """reflow.onnx and reflow_int8.onnx into `model_dir` (None: keep the ones there), the
    manifest's `reflow` record, then the sweep (which may choose the reflowed sampler),
    the judgement of its choice against the exact SMMs (the base flow's defaults serve
    unless it is no worse on `judge_targets` report targets, training/sweep/
    `judged_sweep`) and the quality measurement; all on a hidden copy swapped in only
    when it succeeds."""
    with staged_copy(model_dir) as staging:
        manifest = Manifest.model_validate_json((staging / MANIFEST_FILE).read_bytes())
        incumbent = base_defaults(manifest)
        if student is not None:
            export_flow(student, staging / REFLOW_FILE, manifest.joints.count,
                        len(manifest.condition.names))  # fmt: skip
            quantise_flow(staging / REFLOW_FILE, staging / REFLOW_INT8_FILE)
        files = {
            **manifest.files,
            **{name: sha256_of(staging / name) for name in (REFLOW_FILE, REFLOW_INT8_FILE)},
        }
        manifest = manifest.model_copy(update={"files": files, "reflow": record})
        (staging / MANIFEST_FILE).write_text(
            manifest.model_dump_json(indent=2, exclude_unset=True) + "\n"
        )
        manifest = sweep_and_measure(
            staging, manifest, threads, sweep_targets, sweep_seed, eval_targets,
            eval_samples_per_target, eval_seed, axes=REFLOW_AXES,
            paper_row=paper_row(manifest, eval_targets, eval_samples_per_target),
            incumbent=incumbent, judge_targets=judge_targets,
        )  # fmt: skip
        load_model(staging, threads=threads)
    return manifest


def reflow_record(
    manifest: Manifest, config: ReflowConfig, state: ReflowState, command: str
) -> ReflowRecord:
    """How the reflow of `manifest`'s model was made: by `command` with `config`."""
    return ReflowRecord(
        command=command,
        config=config.as_dict(),
        teacher_sha256=manifest.files[FLOW_FILE],
        device="cpu",
        teacher_wall_time_s=round(state.teacher_wall_time_s, 1),
        wall_time_s=round(state.wall_time_s, 1),
        best_step=state.best_step,
        one_step_endpoint_error=state.best_error,
        torch_version=torch.__version__,
        git_commit=git_commit(),
        base_sampler=base_sampler(manifest),
        processor=Machine.now().processor(),
    )


def base_defaults(manifest: Manifest) -> Defaults:
    """The base flow's serving defaults, which a reflowed sampler must be no worse than:
    the manifest's own while they serve the base flow, else those with the base sampler
    the reflow replaced."""
    defaults = manifest.defaults
    if defaults.sampler.flow == "base":
        return defaults
    sampler = base_sampler(manifest)
    if sampler is None:
        raise ValueError(f"{manifest.model_id}: serves a reflow without a base sampler record")
    return defaults.model_copy(update={"sampler": sampler})


# The sweep's axes a reflow re-measures: the base flow's precision and steps were chosen
# when it was exported; whether the reflowed sampler serves, and what follows from it.
REFLOW_AXES: tuple[Axis, ...] = (
    "reflow_steps",
    "correction_steps",
    "num_samples",
    "connectivity_step_rad",
)


def reflow_model(
    model_dir: Path, runs_dir: Path, config: ReflowConfig, resume: bool, command: str,
    sweep_targets: int | None = None, export_only: bool = False,
) -> Manifest:  # fmt: skip
    """Train (or continue) the reflow of the model in `model_dir` and export it there, or
    (`export_only`) sweep, judge and measure the reflow it already has again; the sweep and
    quality settings are the base training's (its manifest)."""
    torch.set_num_threads(config.threads)
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    base = manifest.training.config

    def setting(name: str) -> int:  # a manifest from before a setting existed: its default
        return int(str(base.get(name, getattr(TrainConfig(), name))))

    student: VelocityField | None = None
    if export_only:
        if manifest.reflow is None or REFLOW_FILE not in manifest.files:
            raise ValueError(
                f"{model_dir}: no reflow to export again; train one first: "
                f"smm-train reflow --model-dir {model_dir}"
            )
        record = manifest.reflow.model_copy(update={"export_git_commit": git_commit()})
    else:
        run_dir = runs_dir / manifest.model_id / "reflow"
        student, state = train_reflow(model_dir, run_dir, config, resume)
        if not math.isfinite(state.best_error):
            raise RuntimeError(f"{run_dir}: the reflowed field's endpoint error is not finite")
        record = reflow_record(manifest, config, state, command)
    return export_reflow(
        model_dir, student, record, threads=config.threads,
        sweep_targets=setting("sweep_targets") if sweep_targets is None else sweep_targets,
        sweep_seed=setting("sweep_seed"), eval_targets=setting("eval_targets"),
        eval_samples_per_target=setting("eval_samples_per_target"),
        eval_seed=setting("eval_seed"), judge_targets=setting("judge_targets"),
    )  # fmt: skip


def reflow_command(model_dir: Path, config: ReflowConfig) -> str:
    """The command that reproduces `config`'s reflow of `model_dir` (non-default flags)."""
    defaults = ReflowConfig()
    flags = [
        arg
        for f in fields(ReflowConfig)
        if getattr(config, f.name) != getattr(defaults, f.name)
        for arg in (f"--{f.name.replace('_', '-')}", str(getattr(config, f.name)))
    ]
    return shlex.join(["smm-train", "reflow", "--model-dir", str(model_dir), *flags])


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train reflow`: the model, the run, and a flag per ReflowConfig field."""
    parser.add_argument("--model-dir", type=Path, required=True)
    parser.add_argument("--runs-dir", type=Path, default=Path("runs"))
    parser.add_argument("--resume", action="store_true")
    parser.add_argument(
        "--export-only", action="store_true",
        help="no training: sweep, judge against the exact SMMs and measure the model's "
        "committed reflow.onnx again (after a change to the sweep, the judge or the pipeline)",
    )  # fmt: skip
    defaults = ReflowConfig()
    for f in fields(ReflowConfig):
        kind = type(getattr(defaults, f.name))
        if kind is bool:
            parser.add_argument(
                f"--{f.name.replace('_', '-')}", action=argparse.BooleanOptionalAction,
                default=None,
            )  # fmt: skip
        else:
            parser.add_argument(f"--{f.name.replace('_', '-')}", type=kind, default=None)
    parser.add_argument(
        "--sweep-targets", type=int, default=None,
        help="targets of the sweep after export (default: the base training's, manifest)",
    )  # fmt: skip


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train reflow`: train (or continue, or only export again) and print the result."""
    del parser  # every check is the options' own
    overrides = {
        f.name: getattr(args, f.name)
        for f in fields(ReflowConfig)
        if getattr(args, f.name) is not None
    }
    config = replace(ReflowConfig(), **overrides)
    manifest = reflow_model(
        args.model_dir, args.runs_dir, config, args.resume,
        reflow_command(args.model_dir, config), args.sweep_targets, args.export_only,
    )  # fmt: skip
    print(json.dumps(manifest.model_dump(include={"defaults", "quality"}), indent=1))
