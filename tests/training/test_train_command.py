"""smm-train train end to end: a tiny model trained, exported and served by the real service.

A URDF the project has never seen (tests/support/small_arm.py: a 4R spatial arm with a
floating joint above its base and a gripper branch, position task, r = 1) trains, exports
and is served through the documented command alone, given without its subcommand
(`smm-train --urdf ...` trains): `--urdf` writes its robot file and URDF copy, the
manifest records the command (as `smm-train train ...`) and a measured reach, and every
configuration the service returns reaches the target by the test's own numpy FK, inside
the limits.

`--from-checkpoint` re-exports a run's best.pt and records the run's commit as the
training's, the exporting commit beside it; a best.pt from before runs stored their commit
takes the commit of the manifest that the same run exported, and no other.

`--refresh-kinematics` re-exports only the kinematics of an existing model directory: it
gains chain.json, its flow is untouched, and the service serves it by the chain.
"""

import json
import shlex
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from service.manifest import CHAIN_FILE, REPO_MODELS_DIR, Manifest
from service.models.chain import SerialChainKinematics
from service.models.registry import load_model, sha256_of
from service.pipeline.joint_space import JointLimits
from tests.support.app import make_client
from tests.support.chains import model_without_chain
from tests.support.small_arm import JOINTS, arm_pose, write_arm
from tests.support.tiny_training import TINY
from training.checkpoint import BestCheckpoint
from training.cli import in_subprocess, main
from training.evaluate.references.planar3r import planar3r_position
from training.machine import Machine
from training.robots import robot_spec
from training.train_command import earlier_training_commit


def test_tiny_model_trains_exports_and_is_served(tmp_path: Path) -> None:
    models, runs = tmp_path / "models", tmp_path / "runs"
    command = [
        *in_subprocess("train"),
        "--robot", "planar3r", "--task", "position",
        "--samples", "4000", "--epochs", "2", "--sweep-targets", "0",
        "--eval-targets", "4", "--eval-samples-per-target", "200",
        "--reflow-steps", "30", "--reflow-pairs", "3000",
        "--models-dir", str(models), "--runs-dir", str(runs),
    ]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]

    model_dir = models / "planar3r-position"
    manifest = Manifest.model_validate_json((model_dir / "manifest.json").read_text())
    assert (manifest.training.samples, manifest.training.epochs) == (4000, 2)
    assert manifest.training.device == "cpu" and manifest.training.wall_time_s > 0
    # The processor that trained it (this one), and that the reflow trained on.
    here = Machine.now().processor()
    assert manifest.training.processor == here and here["cpu"] and here["cores"]
    assert manifest.training.command.startswith("smm-train train --robot planar3r")
    assert np.isfinite(manifest.training.best_validation_loss)
    assert manifest.quality is not None and manifest.quality.held_out_targets == 4
    assert sorted(manifest.files) == [
        "chain.json", "flow.onnx", "flow_int8.onnx", "kinematics.onnx", "reflow.onnx",
        "reflow_int8.onnx",
    ]  # fmt: skip
    # The reflow ran after the export, from the exported flow, and says how to repeat it.
    assert (
        manifest.reflow is not None
        and manifest.reflow.teacher_sha256 == manifest.files["flow.onnx"]
    )
    assert manifest.reflow.command == (
        f"smm-train reflow --model-dir {models / 'planar3r-position'} "
        "--pairs 3000 --validation-pairs 1000 --steps 30 --batch-size 512"
    )
    assert np.isfinite(manifest.reflow.one_step_endpoint_error)
    assert manifest.reflow.processor == here
    for name, digest in manifest.files.items():
        assert sha256_of(model_dir / name) == digest
    assert (runs / "planar3r-position" / "best.pt").is_file()
    assert len(json.loads((runs / "planar3r-position" / "history.json").read_text())) == 2

    with make_client(models) as client:
        target = [1.5, 0.5]
        body = {"robot": "planar3r", "task": "position", "target": {"position": target}}
        response = client.post("/smm", json={**body, "num_samples": 2000})
    assert response.status_code == 200
    answer = response.json()
    assert answer["model"].startswith("planar3r-position@")
    q = np.array([q for c in answer["components"] for q in c["configurations"]]).reshape(-1, 3)
    # Even a barely trained flow, once corrected, returns only exact configurations.
    assert np.all(np.linalg.norm(planar3r_position(q) - target, axis=1) <= 1e-6)

    # Re-exported from its best.pt by later code: the run's commit stays the training's.
    best_path = runs / "planar3r-position" / "best.pt"
    best = torch.load(best_path, weights_only=False)
    assert best["git_commit"] == manifest.training.git_commit
    best["git_commit"] = "0123abc"  # as if the run had started from another commit
    best["processor"] = {"cpu": "Another CPU", "cores": 8}  # ... on another machine
    torch.save(best, best_path)
    again = [*command[:4], "--robot", "planar3r", "--task", "position",
             "--from-checkpoint", str(best_path), *command[8 + 4 :]]  # fmt: skip
    result = subprocess.run(again, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    record = Manifest.model_validate_json((model_dir / "manifest.json").read_text()).training
    assert record.git_commit == "0123abc"
    assert record.processor == {"cpu": "Another CPU", "cores": 8}  # the training's, kept
    assert record.export_git_commit == manifest.training.git_commit  # this checkout's
    assert record.command == manifest.training.command


def test_a_best_checkpoint_without_a_commit_takes_the_same_runs_manifest_commit(
    tmp_path: Path,
) -> None:
    bundled = REPO_MODELS_DIR / "planar3r-position" / "manifest.json"
    (tmp_path / "manifest.json").write_bytes(bundled.read_bytes())
    record = Manifest.model_validate_json(bundled.read_bytes()).training
    same_run = BestCheckpoint(
        config=TINY, state_dict={}, best_validation_loss=record.best_validation_loss,
        best_epoch=record.best_epoch, wall_time_s=1.0, command=record.command,
    )  # fmt: skip
    assert earlier_training_commit(tmp_path, same_run) == record.git_commit
    other_run = replace(same_run, best_epoch=record.best_epoch + 1)
    assert earlier_training_commit(tmp_path, other_run) == "unknown"
    assert earlier_training_commit(tmp_path / "absent", same_run) == "unknown"


def test_a_urdf_never_seen_trains_exports_and_is_served(tmp_path: Path) -> None:
    models, runs = tmp_path / "models", tmp_path / "runs"
    urdf = write_arm(tmp_path, name="Small Arm")
    command = [  # no subcommand: `smm-train --urdf ...` is `smm-train train --urdf ...`
        *in_subprocess(),
        "--urdf", str(urdf), "--end-effector", "tool", "--base-link", "base",
        "--task", "position",
        "--samples", "4000", "--epochs", "2", "--hidden-width", "64", "--hidden-layers", "2",
        "--sweep-targets", "2", "--reflow-steps", "0",
        "--eval-targets", "4", "--eval-samples-per-target", "200",
        "--models-dir", str(models), "--runs-dir", str(runs),
    ]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]

    robot = robot_spec("small_arm", models)  # smm-train --robot small_arm from now on
    assert (models / robot.urdf).read_text() == urdf.read_text()
    assert (robot.base_link, robot.end_effector_link) == ("base", "tool")
    manifest = Manifest.model_validate_json(
        (models / "small_arm-position" / "manifest.json").read_text()
    )
    assert manifest.training.command == shlex.join(["smm-train", "train", *command[3:]])
    # Provenance: the commit the run started from (+dirty if its code had changes).
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True)
    expected = head.stdout.strip() if head.returncode == 0 else "unknown"
    assert manifest.training.git_commit.removesuffix("+dirty") == expected
    assert manifest.joints.names == ["j1", "j2", "j3", "j4"]
    # Its serving defaults were chosen by the built-in sweep, every candidate measured.
    swept = [
        ("sampler_precision", (32, 8)),
        ("sampler", (2, 4, 8, 20)),
        ("num_samples", (500, 1000, 2000)),
        ("connectivity", (0.075, 0.15, 0.3)),  # r = 1: the trace's step
    ]
    for key, values in swept:
        reason = manifest.defaults.reasons[key]
        assert "dense reference" in reason
        assert all(f"; {v}: keep rate" in reason or f": {v}: keep rate" in reason for v in values)
    chosen_step = manifest.defaults.connectivity.trace_step_rad
    assert manifest.defaults.reasons["connectivity"].startswith(f"trace_step_rad = {chosen_step} ")
    limits = JointLimits.of(manifest.joints)
    rng = np.random.default_rng(7)
    sampled_m = [
        np.linalg.norm(arm_pose(q)[:3, 3])
        for q in rng.uniform(limits.lower_rad, limits.upper_rad, (500, 4))
    ]
    links_m = sum(float(np.linalg.norm(xyz)) for _, _, _, _, xyz, *_ in JOINTS[1:7])
    assert max(sampled_m) <= manifest.reach_m <= links_m  # measured, between two bounds

    q_target = rng.uniform(limits.lower_rad, limits.upper_rad)
    target = arm_pose(q_target)[:3, 3]
    with make_client(models) as client:
        assert [m["robot"] for m in client.get("/robots").json()["models"]] == ["small_arm"]
        body = {"robot": "small_arm", "task": "position", "target": {"position": target.tolist()}}
        response = client.post("/smm", json={**body, "num_samples": 1000, "seed": 3})
    assert response.status_code == 200, response.text
    answer = response.json()
    q = np.array([q for c in answer["components"] for q in c["configurations"]]).reshape(-1, 4)
    assert len(q) > 0
    reached = np.array([arm_pose(one)[:3, 3] for one in q])
    assert np.all(np.linalg.norm(reached - target, axis=1) <= 1e-6)
    assert np.all((q >= limits.lower_rad) & (q <= limits.upper_rad))


def test_an_arm_that_cannot_be_trained_is_refused_by_name_before_anything_is_written(
    tmp_path: Path,
) -> None:
    """Without --base-link the chain starts at the URDF's root, above the floating cart."""
    models = tmp_path / "models"
    argv = ["--urdf", str(write_arm(tmp_path)), "--end-effector", "tool", "--task", "position"]
    with pytest.raises(SystemExit, match=r"smm-train: error: joint 'cart' .* is 'floating'"):
        main(["train", *argv, "--models-dir", str(models)])
    with pytest.raises(SystemExit, match=r"unknown robot 'arm'.*choose from \[\]"):
        main(["train", "--robot", "arm", "--task", "position", "--models-dir", str(models)])
    assert not models.exists()


def test_refresh_kinematics_flag_gives_an_existing_model_its_chain(tmp_path: Path) -> None:
    model_dir = model_without_chain(tmp_path)
    flow = sha256_of(model_dir / "flow.onnx")
    argv = ["--robot", "planar3r", "--task", "position", "--models-dir", str(model_dir.parent)]
    main(["train", *argv, "--refresh-kinematics"])
    manifest = Manifest.model_validate_json((model_dir / "manifest.json").read_text())
    assert manifest.files[CHAIN_FILE] == sha256_of(model_dir / CHAIN_FILE)
    assert manifest.files["flow.onnx"] == flow
    assert isinstance(load_model(model_dir, threads=1).kinematics, SerialChainKinematics)
    with pytest.raises(SystemExit):  # it trains nothing, so it does not combine with --resume
        main(["train", *argv, "--refresh-kinematics", "--resume"])


def test_models_go_where_the_service_serves_from(monkeypatch: pytest.MonkeyPatch) -> None:
    """Without --models-dir, smm-train writes where smm-serve reads: SMM_MODELS_DIR when set
    (the service's own setting), else the repository's models/."""
    from service.config import Settings
    from training.train_command import MODELS_DIR_VARIABLE, default_models_dir

    monkeypatch.delenv(MODELS_DIR_VARIABLE, raising=False)
    assert default_models_dir() == REPO_MODELS_DIR == Settings().models_dir
    monkeypatch.setenv(MODELS_DIR_VARIABLE, "/srv/smm/models")
    assert default_models_dir() == Path("/srv/smm/models") == Settings().models_dir
