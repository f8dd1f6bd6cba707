"""smm-train collision, and smm-train train writing collision.json at export.

A tiny model of the collision arm trained through `smm-train --urdf ... --srdf ...`: the
SRDF and the URDF's mesh are copied beside the URDF copy, the model ships collision.json
(in manifest.files with its sha256) and manifest.collision records the SRDF, the
command and a sphere count equal to the spheres in the file; the registry loads it.
`smm-train collision --model` then rebuilds it with other settings after a change to the
URDF's geometry only: the manifest takes the URDF's new sha256 and the new record, every
file verifies, the flow is untouched; after a change to its kinematics the command
refuses, naming the joint and field, and leaves the model as it was; an unknown model
is refused with the models present.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from service.manifest import COLLISION_FILE, CollisionSpec, Manifest
from service.models.registry import load_model, sha256_of
from tests.support.app import make_client
from tests.support.collision_arm import write_collision_arm, write_srdf
from training.cli import in_subprocess, main
from training.evaluate.scenes.coal_model import CoalModel


def _manifest(model_dir: Path) -> Manifest:
    return Manifest.model_validate_json((model_dir / "manifest.json").read_bytes())


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The models directory of a tiny collision_arm-position model."""
    root = tmp_path_factory.mktemp("collision_model")
    urdf = write_collision_arm(root / "source")
    srdf = write_srdf(root / "source", [("l1", "world"), ("base", "l3")])
    models = root / "models"
    command = [
        *in_subprocess("train"), "--urdf", str(urdf), "--srdf", str(srdf),
        "--end-effector", "tool", "--base-link", "base", "--task", "position",
        "--samples", "2000", "--epochs", "1", "--hidden-width", "16", "--hidden-layers", "2",
        "--sweep-targets", "0", "--reflow-steps", "0", "--eval-targets", "2",
        "--eval-samples-per-target", "100", "--models-dir", str(models),
        "--runs-dir", str(root / "runs"),
    ]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    return models


def test_training_writes_the_collision_model_with_the_srdf(trained: Path) -> None:
    """collision.json ships, listed and recorded; the SRDF's pairs are in it."""
    model_dir = trained / "collision_arm-position"
    manifest = _manifest(model_dir)
    assert (trained / "robots" / "collision_arm.srdf").is_file()
    assert (trained / "robots" / "meshes" / "l2.stl").is_file()
    assert manifest.files[COLLISION_FILE] == sha256_of(model_dir / COLLISION_FILE)
    spec = CollisionSpec.model_validate_json((model_dir / COLLISION_FILE).read_bytes())
    record = manifest.collision
    assert record is not None and record.srdf is not None
    assert record.srdf.path == "robots/collision_arm.srdf"
    assert record.command == manifest.training.command
    assert record.urdf_sha256 == manifest.urdf.sha256
    assert record.sphere_count == sum(len(body.radii_m) for body in spec.bodies)
    reasons = {pair.links: pair.reason for pair in spec.disabled_pairs}
    assert reasons[("l1", "world")] == reasons[("base", "l3")] == "srdf"
    load_model(model_dir, threads=1)


def test_the_trained_model_serves_answers_free_of_self_collision(
    trained: Path, tmp_path: Path
) -> None:
    """Served over HTTP (the real app on a copy of that models directory, its collision
    model rebuilt with an SRDF that leaves the world fixture to the scene, as a planner's
    SRDF does), its answers to targets reached by self-collision-free configurations say
    self-collision was checked, and every returned configuration and path point is free
    of self-collision by coal on the URDF's own geometry, outside the SRDF's pairs."""
    models = tmp_path / "models"
    shutil.copytree(trained, models)
    others = ("base", "l1", "l2", "l3", "l4", "tool", "finger_a", "finger_b")
    srdf = write_srdf(tmp_path, [("world", link) for link in others] + [("base", "l3")])
    main(["collision", "--model", "collision_arm-position", "--srdf", str(srdf),
          "--configurations", "300", "--models-dir", str(models)])  # fmt: skip
    model_dir = models / "collision_arm-position"
    coal = CoalModel.of_directory(model_dir)
    served = load_model(model_dir, threads=1)
    limits = served.limits
    q = np.random.default_rng(3).uniform(limits.lower_rad, limits.upper_rad, (60, 4))
    q_targets = q[~coal.robot.in_self_collision(q, coal.disabled)][:6]
    checked = 0
    with make_client(models, max_num_samples=5000) as client:
        for q_target in q_targets:
            position = served.kinematics(q_target[None]).position_m[0].tolist()
            body = {"robot": "collision_arm", "task": "position", "target": {"position": position},
                    "num_samples": 400}  # fmt: skip
            answer = client.post("/smm", json=body).json()
            assert answer["collision"]["self_checked"] is True
            counts = answer["counts"]
            assert counts["sampled"] == counts["accepted"] + counts["rejected_tolerance"] + (
                counts["rejected_joint_limits"] + counts["rejected_collision"]
            )
            points = [
                p for c in answer["components"] for p in c["configurations"] + (c["path"] or [])
            ]
            if points:
                assert not coal.robot.in_self_collision(np.array(points), coal.disabled).any()
                checked += len(points)
    assert checked > 0


def test_the_command_rebuilds_after_a_geometry_change_and_refuses_a_kinematic_one(
    trained: Path,
) -> None:
    """A new tool box size: rebuilt, new URDF sha256 recorded, files verify, the flow
    the same; a moved joint: refused by name, nothing changed."""
    model_dir = trained / "collision_arm-position"
    before = _manifest(model_dir)
    urdf = trained / "robots" / "collision_arm.urdf"
    urdf.write_text(urdf.read_text().replace('size="0.04 0.04 0.04"', 'size="0.05 0.04 0.04"'))
    main([
        "collision", "--model", "collision_arm-position", "--spheres-per-body", "2",
        "--configurations", "200", "--models-dir", str(trained),
    ])  # fmt: skip
    after = _manifest(model_dir)
    assert after.urdf.sha256 == sha256_of(urdf) != before.urdf.sha256
    assert after.collision is not None and after.collision.configurations_sampled == 200
    assert after.collision.command.startswith("smm-train collision --model collision_arm-position")
    assert before.collision is not None
    assert after.collision.srdf == before.collision.srdf  # the robot file's SRDF
    spec = CollisionSpec.model_validate_json((model_dir / COLLISION_FILE).read_bytes())
    assert max(len(body.radii_m) for body in spec.bodies) <= 2
    tool = next(body for body in spec.bodies if body.link == "tool")
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    corners = corners * [0.025, 0.02, 0.02] + [0, 0, 0.1]  # the new box, in frame 4
    gaps = np.linalg.norm(corners[:, None] - np.asarray(tool.centres_m)[None], axis=2)
    assert np.all((gaps - np.asarray(tool.radii_m)).min(axis=1) <= 0)
    assert after.files["flow.onnx"] == before.files["flow.onnx"]
    load_model(model_dir, threads=1)  # every file's sha256, the URDF's too

    j3 = '<child link="l3"/><origin xyz="0 0 0.0'
    urdf.write_text(urdf.read_text().replace(f"{j3}2", f"{j3}3"))  # j3 moved 1 cm
    with pytest.raises(SystemExit, match=r"no longer gives .*joint 'j3' origin"):
        main(["collision", "--model", "collision_arm-position", "--models-dir", str(trained)])
    assert _manifest(model_dir) == after
    with pytest.raises(SystemExit, match=r"--model 'nothing': choose from \['collision_arm"):
        main(["collision", "--model", "nothing", "--models-dir", str(trained)])
