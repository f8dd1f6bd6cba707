"""training.budget: the work after training follows the budget asked, and the plan says so.

- Every bundled model's recorded command (its manifest's `training.command`) gets the full
  work after training, the defaults of training/config.py, as before the scaling existed.
- Under the full budget the sweep, quality and judge targets and the reflow shrink in
  proportion, no lower than their floors; the reflow is off below its floor of steps;
  a flag given is kept as given.
- The plan lists every stage with its estimate or why it does not run (the judge: no
  exact reference, or no reflow to judge), and a larger budget is estimated to take longer.
- A robot whose judge needs a missing evaluation package is refused before training, with
  the install command, unless the reflow (which the judge is for) is off.
"""

import shlex
from dataclasses import replace
from pathlib import Path

import pytest

from service.manifest import MANIFEST_FILE, REPO_MODELS_DIR, Manifest
from tests.support.not_installed import refuse_evaluation_packages
from training.budget import (
    FULL_BUDGET_SAMPLE_EPOCHS,
    MIN_EVAL_TARGETS,
    MIN_JUDGE_TARGETS,
    MIN_REFLOW_STEPS,
    MIN_SWEEP_TARGETS,
    SCALED_FIELDS,
    UnitCosts,
    duration,
    plan_run,
    scaled_config,
)
from training.cli import main
from training.config import TrainConfig
from training.evaluate.packages import no_deps_command
from training.robots import robot_spec
from training.train_command import config_from_args, parse_args

FULL = TrainConfig()
COSTS = UnitCosts(evaluation_s=15e-6, training_sample_s=60e-6)


@pytest.mark.parametrize(
    "model_dir", sorted(p.parent for p in REPO_MODELS_DIR.glob(f"*/{MANIFEST_FILE}"))
)
def test_every_bundled_command_gets_the_full_work_after_training(model_dir: Path) -> None:
    command = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes()).training
    words = shlex.split(command.command)[1:]  # after smm-train; older records lack `train`
    args = parse_args(words[1:] if words[:1] == ["train"] else words)
    config = config_from_args(args, args.robot)
    assert config == config_from_args(args, args.robot, scale=False)
    assert config.samples * config.epochs >= FULL_BUDGET_SAMPLE_EPOCHS
    recorded = command.config
    for name in SCALED_FIELDS:  # as the recorded run had them, or the defaults it predates
        assert getattr(config, name) == recorded.get(name, getattr(FULL, name)), name


def test_a_small_budget_scales_the_work_after_training_down_to_its_floors() -> None:
    tiny = scaled_config(replace(FULL, samples=20_000, epochs=2))
    assert (tiny.sweep_targets, tiny.eval_targets, tiny.judge_targets, tiny.reflow_steps) == (
        MIN_SWEEP_TARGETS, MIN_EVAL_TARGETS, MIN_JUDGE_TARGETS, 0,
    )  # fmt: skip
    tenth = scaled_config(replace(FULL, samples=200_000, epochs=5))  # 1M sample-epochs
    assert (tenth.reflow_steps, tenth.reflow_pairs) == (3_000, 100_000)
    assert (tenth.eval_targets, tenth.judge_targets) == (20, 20)
    assert tenth.sweep_targets == MIN_SWEEP_TARGETS  # 2 in proportion, under the floor
    # The reflow runs from its floor of steps on.
    edge = FULL_BUDGET_SAMPLE_EPOCHS * MIN_REFLOW_STEPS // FULL.reflow_steps
    assert scaled_config(replace(FULL, samples=edge, epochs=1)).reflow_steps == MIN_REFLOW_STEPS
    assert scaled_config(replace(FULL, samples=edge - 1_000, epochs=1)).reflow_steps == 0
    full = replace(FULL, samples=500_000, epochs=50)
    assert scaled_config(full) == full

    given = replace(FULL, samples=4_000, epochs=2, reflow_steps=30, sweep_targets=0)
    kept = scaled_config(given, {"reflow_steps", "sweep_targets"})
    assert (kept.reflow_steps, kept.sweep_targets, kept.reflow_pairs) == (30, 0, 10_000)


def test_the_plan_lists_every_stage_with_its_estimate_or_why_it_does_not_run() -> None:
    task = robot_spec("planar3r").task("position")
    small_full = replace(FULL, robot="planar3r", samples=20_000, epochs=2)
    small = scaled_config(small_full)
    plan = plan_run(small, task, COSTS, full=small_full)
    stages = {stage.name: stage for stage in plan.stages}
    assert list(stages) == ["training", "export", "sweep", "reflow", "judge", "quality"]
    assert stages["reflow"].estimate_s is None and "under 1,000" in stages["reflow"].detail
    assert stages["judge"].estimate_s is None
    assert plan.scaled == SCALED_FIELDS
    lines = plan.lines()
    assert "rough estimates" in lines[0] and "15 us" in lines[0]
    assert lines[-2].split()[0] == "total" and "scaled down" in lines[-1]

    big = plan_run(replace(FULL, robot="planar3r"), task, COSTS, full=FULL)
    judge = {stage.name: stage for stage in big.stages}["judge"]
    assert judge.at_most and judge.estimate_s is not None and "200 report targets" in judge.detail
    assert big.total_s > 10 * plan.total_s and big.scaled == ()
    unjudged = plan_run(replace(FULL, robot="my_arm"), task, COSTS, full=FULL)
    judge = {stage.name: stage for stage in unjudged.stages}["judge"]
    assert judge.estimate_s is None and "no exact reference for robot 'my_arm'" in judge.detail
    checkpoint = plan_run(small, task, COSTS, trains=False, given=SCALED_FIELDS)
    assert checkpoint.stages[0].estimate_s is None and checkpoint.scaled == ()
    assert [duration(s) for s in (0.2, 42, 420, 9000)] == ["~1 s", "~42 s", "~7 min", "~2.5 h"]


def test_a_judge_whose_package_is_missing_is_refused_before_training(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    refuse_evaluation_packages(monkeypatch)
    argv = [
        "--robot", "panda", "--task", "pose", "--samples", "2000000", "--epochs", "5",
        "--models-dir", str(tmp_path / "models"), "--runs-dir", str(tmp_path / "runs"),
    ]  # fmt: skip
    with pytest.raises(SystemExit) as refused:
        main(["train", *argv])
    message = str(refused.value)
    assert message.startswith("smm-train: error: The judge of panda's reflowed sampler needs")
    assert no_deps_command() in message and "--reflow-steps 0" in message
    assert not (tmp_path / "runs").exists()
