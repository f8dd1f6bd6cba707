"""The work `smm-train` does after training, scaled to the training budget, and the plan it
prints before it starts.

A run's budget is its sample-epochs, samples x epochs. At FULL_BUDGET_SAMPLE_EPOCHS and
above, the work after training runs at the defaults of training/config.py: the sweep on
20 targets, the reflow (30,000 steps on 1,000,000 teacher pairs), the judge on 200
targets and the quality measurement on 200, as for every bundled model (the smallest
budget among them, the Panda's 500,000 x 50, is 25,000,000). Below it, each shrinks in
proportion to the budget, down to a floor (`scaled_config`): a trial run that trains in
seconds is not followed by an hour of measurement. A flag given on the command line is
kept as given; `--reflow-steps 0` and `--sweep-targets 0` turn those stages off.

Before anything is labelled, `smm-train` prints the plan (`plan_run`): every stage (training,
export, sweep, reflow, judge, quality), what it will do or why it will not run, and a
rough estimate of its wall time on this machine. The estimate counts the stage's
network evaluations and training samples, its dominant costs, and multiplies them by the
cost of one, measured when the command starts with the run's own architecture and
threads (`measure_costs`); the rest of each query (correction, acceptance,
connectivity), the export and the exact references of the judge are constants measured
on a 2-core AMD EPYC machine. It is an estimate: a model that keeps more samples has
more to connect, and a busy machine is slower.
"""

from __future__ import annotations

import math
import time
from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace
from typing import Any

import torch

from service.manifest import TaskSpec
from training.config import TrainConfig
from training.defaults import START_NUM_SAMPLES, START_SAMPLER_STEPS
from training.evaluate.judge import DRAWS, near_singular_for, robot_has_ground_truth
from training.evaluate.packages import installed, missing_message
from training.evaluate.quality import PAPER_SAMPLER
from training.evaluate.truth import REFERENCE_PACKAGES
from training.model import VelocityField
from training.reflow import REFLOW_AXES, ReflowConfig
from training.sweep import AXES, Axis, SweepPlan

# At this many sample-epochs (200,000 samples x 50 epochs, say) and above, the work after
# training runs at the defaults of training/config.py; below, in proportion. It sits under
# every bundled model's budget (the smallest, the Panda's, is 25M), so each recorded
# command still reproduces with the full work, and a run of 2.5x less still gets it; a
# trial of 20,000 x 2 (0.4 % of it) gets the floors below.
FULL_BUDGET_SAMPLE_EPOCHS = 10_000_000
# Floors of the scaled work. 5 sweep targets: count right moves in steps of 20 %, coarse
# but more than one answer deciding each axis. 10 quality targets: a keep rate and raw
# errors over 10,000 samples. 20 judge targets (and 2 near-singular ones): a reflowed
# sampler that loses components on more than one target in ten is seen.
MIN_SWEEP_TARGETS = 5
MIN_EVAL_TARGETS = 10
MIN_JUDGE_TARGETS = 20
# Under this many optimiser steps (one validation interval of training/reflow.py) a reflow
# cannot straighten the paths: the reflow is off unless --reflow-steps is given.
MIN_REFLOW_STEPS = ReflowConfig().validate_every
MIN_REFLOW_PAIRS = 10_000
# The TrainConfig fields scaled, each kept when its flag is given.
SCALED_FIELDS = ("reflow_steps", "reflow_pairs", "sweep_targets", "judge_targets", "eval_targets")

# Constants of the estimate, measured on a 2-core AMD EPYC machine (2 torch threads):
# the export of a 7-joint arm's 512 x 5 flow (flow.onnx, its int8 copy, kinematics.onnx,
# chain.json, every parity check) took 11 s;
EXPORT_S = 12.0
# a query's work besides the network (correction, acceptance, connectivity) per 1000
# samples, on a barely trained 7-joint arm (more where more samples are kept);
QUERY_OVERHEAD_S = 0.03
# the exact SMM of one target (training/evaluate/truth.py), the judge's ground truth, by
# robot and task (4 targets each).
GROUND_TRUTH_S: dict[tuple[str, str], float] = {
    ("planar3r", "position"): 0.001,
    ("iiwa14", "pose"): 0.15,
    ("iiwa14", "position"): 2.1,
    ("panda", "pose"): 0.35,
    ("panda", "position"): 2.6,
}


def sample_epochs(config: TrainConfig) -> int:
    return config.samples * config.epochs


def budget_fraction(config: TrainConfig) -> float:
    """The run's budget as a fraction of the full one, at most 1."""
    return min(1.0, sample_epochs(config) / FULL_BUDGET_SAMPLE_EPOCHS)


def scaled_config(config: TrainConfig, given: Collection[str] = ()) -> TrainConfig:
    """`config` (its SCALED_FIELDS at their full-budget values) with the work after training
    scaled to its budget: each field times `budget_fraction`, rounded, no lower than its
    floor (nor than the full value); the reflow off when its steps fall under
    MIN_REFLOW_STEPS. Fields named in `given` (flags on the command line) are kept."""
    fraction = budget_fraction(config)

    def scaled(name: str, floor: int) -> int:
        full: int = getattr(config, name)
        return max(min(full, floor), round(full * fraction))

    reflow_steps = round(config.reflow_steps * fraction)
    values: dict[str, Any] = {
        "reflow_steps": reflow_steps if reflow_steps >= MIN_REFLOW_STEPS else 0,
        "reflow_pairs": scaled("reflow_pairs", MIN_REFLOW_PAIRS),
        "sweep_targets": scaled("sweep_targets", MIN_SWEEP_TARGETS),
        "judge_targets": scaled("judge_targets", MIN_JUDGE_TARGETS),
        "eval_targets": scaled("eval_targets", MIN_EVAL_TARGETS),
    }
    return replace(config, **{name: v for name, v in values.items() if name not in given})


# -- the estimate ------------------------------------------------------------------------------


@dataclass(frozen=True)
class UnitCosts:
    """Seconds per unit of work on this machine (`measure_costs`)."""

    evaluation_s: float  # one sample through the flow network, float32, batch 1000
    training_sample_s: float  # one sample of a training step: forward, backward, AdamW


def measure_costs(config: TrainConfig, joint_dim: int, condition_dim: int) -> UnitCosts:
    """The run's network, untrained, timed on this machine: the fastest of a few batches of
    1000 evaluations, on torch's threads or on one, whichever is faster (while another
    job holds a core, threads that wait on each other are slower than one by orders of
    magnitude), and of a few training steps of
    `config.batch_size` (on `config.device`, on torch's threads, with the run's bf16
    autocast). Takes about a second on 2 cores for the 512 x 5 net; the global random
    state is left as it was."""
    device = torch.device(config.device)
    with torch.random.fork_rng(devices=[]):  # every tensor is drawn on the CPU
        model = VelocityField(
            joint_dim, condition_dim, config.hidden_width, config.hidden_layers,
            config.time_embedding_dim, config.architecture,
        )  # fmt: skip
        q, t = torch.randn(1000, joint_dim), torch.rand(1000, 1)
        c = torch.randn(1000, condition_dim)
        evaluation = []
        threads = torch.get_num_threads()
        with torch.inference_mode():
            for count in sorted({threads, 1}):
                torch.set_num_threads(count)
                for _ in range(4):
                    start = time.perf_counter()
                    model(q, t, c)
                    evaluation.append((time.perf_counter() - start) / 1000)
        torch.set_num_threads(threads)
        model = model.to(device)
        batch = max(1, config.batch_size)
        q, t, c = (x.to(device) for x in (torch.randn(batch, joint_dim), torch.rand(batch, 1),
                                          torch.randn(batch, condition_dim)))  # fmt: skip
        optimiser = torch.optim.AdamW(model.parameters(), lr=config.learning_rate)
        step = []
        for _ in range(3):
            start = time.perf_counter()
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=config.autocast_bf16):
                loss = ((model(q, t, c) - q) ** 2).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            if device.type == "cuda":
                torch.cuda.synchronize()
            step.append((time.perf_counter() - start) / batch)
    # The first training step is a warm-up (allocations, AdamW's state, autocast's casts).
    return UnitCosts(evaluation_s=min(evaluation[1:]), training_sample_s=min(step[1:]))


def _query_s(costs: UnitCosts, samples: int, steps: int) -> float:
    """One query of `samples` samples at `steps` network steps (sample, correct, connect)."""
    return samples * steps * costs.evaluation_s + QUERY_OVERHEAD_S * samples / 1000


def sweep_target_s(
    costs: UnitCosts, axes: Sequence[Axis] = AXES, reflowed: bool = False,
    plan: SweepPlan | None = None,
) -> float:  # fmt: skip
    """One target of a sweep over `axes` (training/sweep/): the dense reference, the time
    grid's powers, and every candidate of every axis at the starting samples and steps
    (`reflowed`: the model has a reflowed network, whose axis is swept jointly with the
    DLS steps). An upper bound: the sweep measures a setting once however many axes hold
    it, and its later axes run at the cheaper precision and sampler steps it chose."""
    plan = plan or SweepPlan()
    n, steps = START_NUM_SAMPLES, START_SAMPLER_STEPS
    total = _query_s(costs, plan.reference_samples, plan.reference_sampler_steps)
    if "sampler_steps" in axes:
        total += len(plan.time_powers) * n * steps * costs.evaluation_s  # raw samples only
    for axis in axes:
        if axis == "sampler_steps":
            total += sum(_query_s(costs, n, k) for k in plan.sampler_steps)
        elif axis == "num_samples":
            total += sum(_query_s(costs, k, steps) for k in plan.num_samples)
        elif axis == "reflow_steps":
            if reflowed:
                per_dls = sum(_query_s(costs, n, k or steps) for k in plan.reflow_steps)
                total += per_dls * len(plan.correction_steps)
        else:
            total += len(plan.candidates(axis)) * _query_s(costs, n, steps)
    return total


def quality_s(config: TrainConfig, costs: UnitCosts, paper_row: bool = True) -> float:
    """training/evaluate/quality.py: every target at the serving sampler (its steps taken as
    the starting ones) and, unless kept from an earlier measurement, the paper's."""
    steps = START_SAMPLER_STEPS + (PAPER_SAMPLER.steps if paper_row else 0)
    per_target = config.eval_samples_per_target * steps * costs.evaluation_s
    return config.eval_targets * (per_target + QUERY_OVERHEAD_S)


def reflow_s(config: TrainConfig, costs: UnitCosts) -> float:
    """training/reflow.py: the teacher pairs, the fine-tuning and its validations, the
    export, the sweep of the reflowed sampler and the quality measured again."""
    reflow = ReflowConfig()
    validation_pairs = min(reflow.validation_pairs, max(1000, config.reflow_pairs // 10))
    pairs = config.reflow_pairs + validation_pairs
    teacher = pairs * reflow.teacher_steps * costs.evaluation_s
    steps = config.reflow_steps * config.batch_size * costs.training_sample_s
    validations = (config.reflow_steps // reflow.validate_every + 2) * validation_pairs
    sweep = config.sweep_targets * sweep_target_s(costs, REFLOW_AXES, reflowed=True)
    return (
        teacher + steps + validations * costs.evaluation_s + EXPORT_S + sweep
        + quality_s(config, costs, paper_row=False)
    )  # fmt: skip


def judge_s(config: TrainConfig, costs: UnitCosts, robot: str, task: str) -> float:
    """One judgement (training/evaluate/judge.py): the exact SMM of each target, and the
    candidate's and the incumbent's answers, DRAWS of each."""
    targets = config.judge_targets + near_singular_for(config.judge_targets)
    truth = GROUND_TRUTH_S.get((robot, task), max(GROUND_TRUTH_S.values()))
    answers = 2 * DRAWS * _query_s(costs, START_NUM_SAMPLES, START_SAMPLER_STEPS)
    return targets * (truth + answers)


def training_s(config: TrainConfig, costs: UnitCosts) -> float:
    """The epochs' training steps (one device per process) and validation passes."""
    train_samples = config.samples * (1.0 - config.validation_fraction)
    validation = config.samples * config.validation_fraction
    per_epoch = train_samples * costs.training_sample_s / config.world_size
    per_epoch += validation * costs.evaluation_s
    return config.epochs * per_epoch


# -- the plan ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Stage:
    """One stage of the run: what it does (or why it does not run) and how long it may take."""

    name: str
    detail: str
    estimate_s: float | None  # None: it does not run
    at_most: bool = False  # it runs only if an earlier stage decides so


@dataclass(frozen=True)
class Plan:
    """The stages of one `smm-train` run and the budget they were scaled to."""

    stages: tuple[Stage, ...]
    sample_epochs: int
    fraction: float
    scaled: tuple[str, ...]  # SCALED_FIELDS this budget changed (flags given excluded)
    costs: UnitCosts

    @property
    def total_s(self) -> float:
        return sum(s.estimate_s for s in self.stages if s.estimate_s is not None)

    def lines(self) -> list[str]:
        """The plan as `smm-train` prints it."""
        lines = [
            "plan (wall times are rough estimates for this machine, from the cost of one "
            f"network evaluation measured here just now, {self.costs.evaluation_s * 1e6:.0f} "
            f"us, and of one training sample, {self.costs.training_sample_s * 1e6:.0f} us; "
            "stages that connect many kept samples take longer):"
        ]
        width = max(len(stage.name) for stage in self.stages)
        for stage in self.stages:
            when = "not run" if stage.estimate_s is None else duration(stage.estimate_s)
            if stage.at_most and stage.estimate_s is not None:
                when = f"up to {when}"
            lines.append(f"  {stage.name:<{width}}  {when:>14}  {stage.detail}")
        lines.append(f"  {'total':<{width}}  {duration(self.total_s):>14}")
        budget = f"budget: {self.sample_epochs:,} sample-epochs (samples x epochs), " + (
            f"{self.fraction:.1%} of the full budget {FULL_BUDGET_SAMPLE_EPOCHS:,}"
            if self.fraction < 1.0
            else f"the full work after training (from {FULL_BUDGET_SAMPLE_EPOCHS:,} up)"
        )
        if self.scaled:
            flags = ", ".join(f"--{name.replace('_', '-')}" for name in self.scaled)
            budget += f"; the work after training is scaled down ({flags} set it)"
        lines.append(budget)
        return lines


def duration(seconds: float) -> str:
    """~42 s, ~7 min, ~2.5 h."""
    if seconds < 90:
        return f"~{max(1, round(seconds))} s"
    if seconds < 90 * 60:
        return f"~{round(seconds / 60)} min"
    return f"~{seconds / 3600:.1f} h"


def judge_package_missing(robot: str) -> str | None:
    """Why the judge cannot run for `robot` here (its reference's package is missing), else
    None."""
    package = REFERENCE_PACKAGES.get(robot)
    if package is None or installed(package):
        return None
    return missing_message(package, f"The judge of {robot}'s reflowed sampler")


def judge_stage(config: TrainConfig, task: TaskSpec, costs: UnitCosts) -> Stage:
    """The judge's stage of the plan: what it judges, or why it does not run."""
    robot = config.robot
    if config.reflow_steps <= 0 or config.sweep_targets <= 0:
        return Stage(
            "judge", "it judges the reflow's sweep, and the reflow or the sweep is off", None
        )  # fmt: skip
    if not robot_has_ground_truth(robot):
        return Stage(
            "judge", f"no exact reference for robot {robot!r}: the sweep's choice serves "
            "unjudged", None,
        )  # fmt: skip
    near = near_singular_for(config.judge_targets)
    return Stage(
        "judge",
        f"{config.judge_targets} report targets and {near} near-singular ones, {DRAWS} "
        "draws each, against the exact SMMs, if the reflow's sweep changes what serves "
        "(each further candidate judged costs as much again)",
        judge_s(config, costs, robot, task.name),
        at_most=True,
    )


def plan_run(
    config: TrainConfig, task: TaskSpec, costs: UnitCosts, *, trains: bool = True,
    given: Collection[str] = (), full: TrainConfig | None = None,
) -> Plan:  # fmt: skip
    """The stages `smm-train` runs for `config` (already scaled; `full`: the same before
    scaling, to name what the budget changed; `given`: the flags given); `trains`: False
    for --from-checkpoint, which trains nothing."""
    samples_per_epoch = round(config.samples * (1.0 - config.validation_fraction))
    if trains:
        steps = math.ceil(samples_per_epoch / (config.batch_size * config.world_size))
        training = Stage(
            "training",
            f"{config.epochs} epochs of {samples_per_epoch:,} samples ({steps:,} steps of "
            f"{config.batch_size} an epoch) on {config.device}",
            training_s(config, costs),
        )
    else:
        training = Stage("training", "none: the checkpoint's flow is exported as it is", None)
    stages = [
        training,
        Stage("export", "flow.onnx, flow_int8.onnx, kinematics.onnx, chain.json", EXPORT_S),
    ]
    if config.sweep_targets > 0:
        plan = SweepPlan()
        stages.append(Stage(
            "sweep",
            f"serving defaults on {config.sweep_targets} held-out targets against a dense "
            f"reference of {plan.reference_samples} samples",
            config.sweep_targets * sweep_target_s(costs),
        ))  # fmt: skip
    else:
        stages.append(Stage(
            "sweep", "off (--sweep-targets 0): the starting defaults of training/defaults.py "
            "serve", None,
        ))  # fmt: skip
    if config.reflow_steps > 0:
        stages.append(Stage(
            "reflow",
            f"{config.reflow_steps:,} steps on {config.reflow_pairs:,} teacher pairs, then "
            "the reflowed sampler swept and the quality measured again",
            reflow_s(config, costs),
        ))  # fmt: skip
    elif "reflow_steps" in given or full is None or full.reflow_steps == 0:
        stages.append(Stage("reflow", "off (--reflow-steps 0)", None))
    else:
        share = round(full.reflow_steps * budget_fraction(config))
        stages.append(Stage(
            "reflow", f"off: this budget's share is {share:,} steps, under "
            f"{MIN_REFLOW_STEPS:,} (--reflow-steps N runs it)", None,
        ))  # fmt: skip
    stages.append(judge_stage(config, task, costs))
    stages.append(Stage(
        "quality",
        f"{config.eval_targets} held-out targets x {config.eval_samples_per_target} samples, "
        f"at the serving sampler and the paper's {PAPER_SAMPLER.steps} steps",
        quality_s(config, costs),
    ))  # fmt: skip
    scaled = tuple(
        name for name in SCALED_FIELDS
        if full is not None and name not in given and getattr(config, name) != getattr(full, name)
    )  # fmt: skip
    return Plan(tuple(stages), sample_epochs(config), budget_fraction(config), scaled, costs)
