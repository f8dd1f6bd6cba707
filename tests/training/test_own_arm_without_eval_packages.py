"""Training and serving need no evaluation package: `eaik` and `realtime-smm` are imported only
where the Panda's exact reference or the Fourier baseline runs.

A 7-joint arm the project has never seen (xArm7-like: seven revolute joints, four of them
turning through 4 pi, a fixed end-effector link), written by the test, trains through
`smm-train train --urdf ... --task pose` in a process where neither package can be imported
(tests/support/not_installed.py: the import system refuses them, as an environment
without them would). The budget is tiny and no flag sets the work after training, so
the command scales it down itself and prints its plan first: the sweep on its floor of
targets, the reflow off, the judge not run. The model is then served by the real app in process, and
every configuration it returns reaches the target pose by the test's own float64 FK of
the URDF (training/evaluate/references/urdf_chain.py), within the joint limits.

Where the packages are needed, their absence raises MissingEvaluationPackage, whose
message names the one command that installs them (the command tools/lock.py pins).
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from service.manifest import Manifest
from service.pipeline.joint_space import JointLimits
from tests.support.app import make_client
from tests.support.not_installed import RUN_SMM_TRAIN, refuse_evaluation_packages
from tools import lock
from training.evaluate.baselines import fourier
from training.evaluate.packages import MissingEvaluationPackage, no_deps_command
from training.evaluate.references import panda
from training.evaluate.references.urdf_chain import read_chain

ROOT = Path(__file__).resolve().parents[2]

# An xArm7-like 7R arm (link offsets and limits in the manner of UFACTORY's xArm7), written
# here so that no file of the project describes it.
JOINTS = [  # (xyz, rpy, lower, upper)
    ("0 0 0.267", "0 0 0", -6.283, 6.283),
    ("0 0 0", "-1.5708 0 0", -2.059, 2.0944),
    ("0 -0.293 0", "1.5708 0 0", -6.283, 6.283),
    ("0.0525 0 0", "1.5708 0 0", -0.19198, 3.927),
    ("0.0775 -0.3425 0", "1.5708 0 0", -6.283, 6.283),
    ("0 0 0", "1.5708 0 0", -1.69297, 3.14159),
    ("0.076 0.097 0", "-1.5708 0 0", -6.283, 6.283),
]


def write_seven_joint_arm(directory: Path) -> Path:
    links = ["link_base", *(f"link{i}" for i in range(1, 8)), "link_eef"]
    text = '<?xml version="1.0"?>\n<robot name="Seven Arm">\n'
    text += "".join(f'  <link name="{link}"/>\n' for link in links)
    for i, (xyz, rpy, lower, upper) in enumerate(JOINTS, start=1):
        text += (
            f'  <joint name="joint{i}" type="revolute"><parent link="{links[i - 1]}"/>'
            f'<child link="{links[i]}"/><origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="0 0 1"/>'
            f'<limit lower="{lower}" upper="{upper}" effort="30" velocity="3.14"/></joint>\n'
        )
    text += (
        '  <joint name="joint_eef" type="fixed"><parent link="link7"/><child link="link_eef"/>'
        '<origin xyz="0 0 0.1" rpy="0 0 0"/></joint>\n</robot>\n'
    )
    path = directory / "seven_arm.urdf"
    path.write_text(text)
    return path


def test_a_seven_joint_arm_trains_and_is_served_without_the_evaluation_packages(
    tmp_path: Path,
) -> None:
    models, runs = tmp_path / "models", tmp_path / "runs"
    urdf = write_seven_joint_arm(tmp_path)
    command = [
        sys.executable, "-c", RUN_SMM_TRAIN, "train",
        "--urdf", str(urdf), "--end-effector", "link_eef", "--task", "pose",
        "--samples", "2000", "--epochs", "2", "--hidden-width", "64", "--hidden-layers", "2",
        "--batch-size", "256", "--models-dir", str(models), "--runs-dir", str(runs),
    ]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "No module named" not in result.stderr

    # The plan came first, with every stage; the tiny budget scaled the work after training.
    plan = [line for line in result.stdout.splitlines() if line.startswith("[seven_arm-pose] ")]
    assert "plan (wall times are rough estimates" in plan[0]
    stages = [line.split()[1] for line in plan[1:8]]
    assert stages == ["training", "export", "sweep", "reflow", "judge", "quality", "total"]
    assert "off: this budget's share is" in plan[4] and "not run" in plan[5]
    assert plan.index(next(line for line in plan if "labelling" in line)) > 8

    manifest = Manifest.model_validate_json(
        (models / "seven_arm-pose" / "manifest.json").read_text()
    )
    config = manifest.training.config
    assert (config["sweep_targets"], config["eval_targets"], config["reflow_steps"]) == (5, 10, 0)
    assert manifest.reflow is None and "dense reference" in manifest.defaults.reasons["sampler"]

    chain = read_chain(urdf, "link_eef")
    limits = JointLimits.of(manifest.joints)
    q_target = np.random.default_rng(5).uniform(limits.lower_rad, limits.upper_rad)
    pose = chain.pose(q_target[None])[0]
    x, y, z, w = Rotation.from_matrix(pose[:3, :3]).as_quat()
    body = {
        "robot": "seven_arm",
        "task": "pose",
        "target": {
            "position": pose[:3, 3].tolist(),
            "orientation": {"w": w, "x": x, "y": y, "z": z},
        },
        "num_samples": 1000,
        "seed": 2,
    }
    with make_client(models) as client:
        response = client.post("/smm", json=body)
    assert response.status_code == 200, response.text
    answer = response.json()
    q = np.array([q for c in answer["components"] for q in c["configurations"]]).reshape(-1, 7)
    assert answer["status"] == "ok" and len(q) > 0
    reached = chain.pose(q)
    assert np.all(np.linalg.norm(reached[:, :3, 3] - pose[:3, 3], axis=1) <= 1e-6)
    turn = np.einsum("bji,jk->bik", reached[:, :3, :3], pose[:3, :3])  # R_reached^T R_target
    angle = np.arccos(np.clip((np.trace(turn, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert np.all(angle <= 1e-6)
    assert np.all((q >= limits.lower_rad - 1e-12) & (q <= limits.upper_rad + 1e-12))


def test_a_missing_evaluation_package_is_named_with_the_command_that_installs_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    refuse_evaluation_packages(monkeypatch)
    assert no_deps_command() == lock.no_deps_command()  # one command, pinned by the lock
    assert no_deps_command() == (
        "pip install -c constraints.txt --no-deps eaik==1.2.2 realtime-smm==0.1.2"
    )
    with pytest.raises(MissingEvaluationPackage) as raised:
        panda.pose_smm(np.array([0.4, 0.0, 0.5]), np.eye(3), q7_steps=3)
    message = str(raised.value)
    assert message.startswith("The Panda's exact reference")
    assert "eaik 1.2.2, which is not installed" in message
    assert message.endswith(f"install it with: {no_deps_command()}")
    assert raised.value.name == "eaik"

    with pytest.raises(MissingEvaluationPackage, match="Fourier baseline") as raised:
        fourier.planar3r_robot()
    assert str(raised.value).endswith(no_deps_command())
