"""robots: the robot list is data, one models/robots/<name>.json per robot.

Every bundled robot file loads, names a URDF that is there and a chain that loads from
it; the planar 3R is a position task in the x-y plane, the iiwa14 has pose and position;
`preset` takes the architecture from the file (the paper's Table 3). An unknown robot
lists the robot files present. `register_urdf` copies a URDF the project has never seen
and writes a robot file that `robot_spec` reads back, with the tasks the chain is
redundant for and the architecture chosen by size; it writes nothing for an arm it
cannot train, keeps an identical registration and refuses another URDF under a taken name.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from service.manifest import REPO_MODELS_DIR, TaskSpec
from tests.support.small_arm import write_arm
from training.config import preset
from training.kinematics import joint_spec, load_chain
from training.robots import (
    Architecture,
    default_architecture,
    register_urdf,
    robot_file,
    robot_names,
    robot_spec,
)


@pytest.mark.parametrize("name", robot_names())
def test_every_bundled_robot_file_loads_its_chain(name: str) -> None:
    robot = robot_spec(name)
    raw = json.loads(robot_file(name).read_text())
    srdf = ["srdf"] if "srdf" in raw else []  # optional: the collision model's pairs
    assert list(raw) == [
        "name", "urdf", *srdf, "base_link", "end_effector_link", "tasks", "architecture",
        "source",
    ]  # fmt: skip
    assert robot.srdf is None or (REPO_MODELS_DIR / robot.srdf).is_file()
    chain = load_chain(REPO_MODELS_DIR / robot.urdf, robot.end_effector_link, robot.base_link)
    assert chain.idx_to_frame[0] == robot.base_link
    assert all(robot.task(task).dimension < joint_spec(chain).count for task in robot.tasks)


def test_the_bundled_robots_keep_their_tasks_and_the_papers_architectures() -> None:
    assert {"planar3r", "iiwa14"} <= set(robot_names())
    planar, iiwa = robot_spec("planar3r"), robot_spec("iiwa14")
    assert planar.task("position") == TaskSpec(
        name="position", position_axes=[0, 1], orientation=False
    )
    assert iiwa.task("pose") == TaskSpec(name="pose", position_axes=[0, 1, 2], orientation=True)
    assert (planar.base_link, planar.end_effector_link) == ("base_link", "ee")
    config = preset("planar3r", "position")
    assert (config.batch_size, config.hidden_width, config.hidden_layers) == (512, 256, 4)
    config = preset("iiwa14", "pose")
    assert (config.batch_size, config.hidden_width, config.hidden_layers) == (1024, 512, 5)
    with pytest.raises(ValueError, match=r"unknown task 'pose' for robot 'planar3r'; choose from"):
        preset("planar3r", "pose")


def test_an_unknown_robot_lists_the_robot_files() -> None:
    with pytest.raises(ValueError, match=r"unknown robot 'ur10'.*choose from \[.*'iiwa14'.*\]"):
        robot_spec("ur10")
    with pytest.raises(ValueError, match=r"unknown robot '\.\./robots/iiwa14'"):
        robot_spec("../robots/iiwa14")


def test_a_registered_urdf_is_a_robot_file(tmp_path: Path) -> None:
    source = tmp_path / "source"
    source.mkdir()
    urdf = write_arm(source, name="My Arm v2")
    models = tmp_path / "models"
    robot = register_urdf(urdf, "tool", "position", models, base_link="base")
    assert robot.name == "my_arm_v2" and robot.urdf == "robots/my_arm_v2.urdf"
    assert (models / robot.urdf).read_text() == urdf.read_text()
    assert robot_spec("my_arm_v2", models) == robot
    assert sorted(robot.tasks) == ["position"]  # 4 joints: no redundancy for the pose
    assert (
        robot.architecture
        == default_architecture(4)
        == Architecture(batch_size=1024, hidden_width=512, hidden_layers=5)
    )
    assert default_architecture(3).hidden_width == 256
    assert (robot.base_link, robot.end_effector_link) == ("base", "tool")
    # The same URDF again is the same robot; another one under the name is refused.
    assert register_urdf(urdf, "tool", "position", models, base_link="base") == robot
    with pytest.raises(ValueError, match=r"robot 'my_arm_v2' already exists .* pass --name"):
        register_urdf(urdf, "l4", "position", models, base_link="base")
    assert register_urdf(urdf, "l4", "position", models, "base", name="arm-l4").name == "arm-l4"


def test_nothing_is_written_for_an_arm_that_cannot_be_trained(tmp_path: Path) -> None:
    urdf = write_arm(tmp_path)
    models = tmp_path / "models"
    with pytest.raises(ValueError, match=r"n = 4 joints .* m = 6"):
        register_urdf(urdf, "tool", "pose", models, base_link="base")
    with pytest.raises(ValueError, match=r"n = 4 joints .* the 'axis' task m = 5"):
        register_urdf(urdf, "tool", "axis", models, base_link="base")
    with pytest.raises(
        ValueError, match=r"unknown task 'orient'; choose from \['axis', 'pose', 'position'\]"
    ):
        register_urdf(urdf, "tool", "orient", models, base_link="base")
    with pytest.raises(ValueError, match=r"joint 'cart' .* is 'floating'"):
        register_urdf(urdf, "tool", "position", models)
    with pytest.raises(ValueError, match=r"robot name 'My Arm'.*use only lowercase"):
        register_urdf(urdf, "tool", "position", models, "base", name="My Arm")
    assert not models.exists()
