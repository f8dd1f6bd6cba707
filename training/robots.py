"""The robots the project trains, as data: one file each, `models/robots/<name>.json`.

A robot file names its URDF (relative to the models directory, like the manifest's
urdf.path), optionally its SRDF (the same way: the collision model's disabled pairs),
the base and end-effector links of the chain, the tasks trained on it, the flow's
architecture and batch size, and where the URDF comes from:

    {"name": "panda", "urdf": "robots/panda.urdf", "srdf": "robots/panda.srdf",
     "base_link": "panda_link0",
     "end_effector_link": "panda_hand_tcp",
     "tasks": {"pose": {"position_axes": [0, 1, 2], "orientation": true}},
     "architecture": {"batch_size": 1024, "hidden_width": 512, "hidden_layers": 5},
     "source": "where the URDF comes from, its licence, what was changed"}

`smm-train --urdf` writes one (`register_urdf`) so that the model is reproducible by
`smm-train --robot <name>`. The reach is not in the file: export measures it.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from service.manifest import DEFAULT_TOOL_AXIS, REPO_MODELS_DIR, TaskName, TaskSpec
from training.collision.geometry import mesh_references
from training.urdf import (
    ROBOT_NAME_PATTERN,
    SPATIAL_TASKS,
    read_serial_chain,
    require_redundancy,
    sanitise_robot_name,
    task_for_urdf,
)

ROBOTS_DIR = "robots"  # under the models directory: <name>.json and its URDF


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Architecture(_Strict):
    """The flow's MLP (hidden_width x hidden_layers) and the training batch size."""

    batch_size: int = Field(ge=1)
    hidden_width: int = Field(ge=1)
    hidden_layers: int = Field(ge=1)


class TaskAxes(_Strict):
    """A task of the robot file; its name is the key it is filed under."""

    position_axes: list[int]
    orientation: bool
    tool_axis: list[float] | None = Field(
        default=None,
        description="axis task: the tool axis, a unit vector in the end-effector frame (default z)",
    )


class RobotSpec(_Strict):
    name: str = Field(pattern=ROBOT_NAME_PATTERN.pattern)
    urdf: str = Field(description="Relative to the models directory.")
    srdf: str | None = Field(
        default=None,
        description="The robot's SRDF, relative to the models directory: its "
        "disable_collisions are the body pairs the collision model never checks.",
    )
    base_link: str
    end_effector_link: str
    tasks: dict[TaskName, TaskAxes] = Field(min_length=1)
    architecture: Architecture
    source: str = Field(description="Where the URDF comes from, its licence, what was changed.")

    def task(self, name: str) -> TaskSpec:
        for task_name, axes in self.tasks.items():
            if task_name == name:
                tool_axis = axes.tool_axis
                if task_name == "axis" and tool_axis is None:
                    tool_axis = list(DEFAULT_TOOL_AXIS)
                return TaskSpec(
                    name=task_name,
                    position_axes=axes.position_axes,
                    orientation=axes.orientation,
                    tool_axis=tool_axis,
                )
        raise ValueError(
            f"unknown task {name!r} for robot {self.name!r}; choose from {sorted(self.tasks)}"
        )


def default_architecture(joint_count: int) -> Architecture:
    """The paper's architectures by size, for a robot that has no file yet: its 3R's
    256 x 4 with batch 512 for n <= 3 joints, its iiwa's 512 x 5 with batch 1024 beyond."""
    if joint_count <= 3:
        return Architecture(batch_size=512, hidden_width=256, hidden_layers=4)
    return Architecture(batch_size=1024, hidden_width=512, hidden_layers=5)


def robot_file(name: str, models_dir: Path = REPO_MODELS_DIR) -> Path:
    return models_dir / ROBOTS_DIR / f"{name}.json"


def robot_names(models_dir: Path = REPO_MODELS_DIR) -> list[str]:
    """The robots with a file in `models_dir`/robots."""
    return sorted(path.stem for path in (models_dir / ROBOTS_DIR).glob("*.json"))


def robot_spec(name: str, models_dir: Path = REPO_MODELS_DIR) -> RobotSpec:
    """The robot file `models_dir`/robots/<name>.json; raises with the robots present otherwise."""
    path = robot_file(name, models_dir)
    if not ROBOT_NAME_PATTERN.match(name) or not path.is_file():
        raise ValueError(
            f"unknown robot {name!r}: no {path}; choose from {robot_names(models_dir)} "
            "(or train a new one with --urdf)"
        )
    try:
        spec = RobotSpec.model_validate_json(path.read_bytes())
    except ValidationError as error:
        raise ValueError(f"{path}: not a valid robot file: {error}") from None
    if spec.name != name:
        raise ValueError(f"{path}: names the robot {spec.name!r}, not {name!r}")
    return spec


def register_urdf(
    urdf_path: Path,
    end_effector_link: str,
    task: str,
    models_dir: Path = REPO_MODELS_DIR,
    base_link: str | None = None,
    name: str | None = None,
    srdf_path: Path | None = None,
) -> RobotSpec:
    """Copy a URDF to `models_dir`/robots/<name>.urdf and write its robot file; return it.

    The collision meshes the URDF names by relative filenames are copied beside it, to the
    same relative paths under `models_dir`/robots (`copy_meshes`), and `srdf_path`, when
    given, to `models_dir`/robots/<name>.srdf (the robot file's srdf).

    The chain is validated first (`training.urdf`: links, joint types, limits, and
    redundancy for `task`), so nothing is written for an arm that cannot be trained.
    The file lists every spatial task the chain is redundant for. `name` defaults to the
    URDF's robot name, sanitised to [a-z0-9_-]. A robot file of that name already there
    is kept when it names the same URDF content and links, and refused otherwise.
    """
    urdf_text = urdf_path.read_text()
    chain = read_serial_chain(urdf_text, end_effector_link, base_link)
    require_redundancy(chain, task_for_urdf(task))
    name = sanitise_robot_name(chain.robot_name) if name is None else name
    if not ROBOT_NAME_PATTERN.match(name):
        raise ValueError(f"robot name {name!r}: use only lowercase letters, digits, '_' and '-'")
    tasks: dict[TaskName, TaskAxes] = {}
    for spatial in SPATIAL_TASKS.values():
        if spatial.dimension < len(chain.movable_joint_names):
            tasks[spatial.name] = TaskAxes(
                position_axes=spatial.position_axes,
                orientation=spatial.orientation,
                tool_axis=spatial.tool_axis,
            )
    digest = hashlib.sha256(urdf_text.encode()).hexdigest()
    spec = RobotSpec(
        name=name,
        urdf=f"{ROBOTS_DIR}/{name}.urdf",
        srdf=None if srdf_path is None else f"{ROBOTS_DIR}/{name}.srdf",
        base_link=chain.base_link,
        end_effector_link=end_effector_link,
        tasks=tasks,
        architecture=default_architecture(len(chain.movable_joint_names)),
        source=f"copied by smm-train --urdf from {urdf_path.name} (sha256 {digest}); "
        "origin and licence not recorded",
    )
    path, urdf_copy = robot_file(name, models_dir), models_dir / spec.urdf
    if path.exists():
        existing = robot_spec(name, models_dir)
        same_urdf = (models_dir / existing.urdf).is_file() and (
            models_dir / existing.urdf
        ).read_text() == urdf_text
        same_links = (existing.base_link, existing.end_effector_link) == (
            spec.base_link,
            spec.end_effector_link,
        )
        same_srdf = existing.srdf == spec.srdf and (
            srdf_path is None or _same_content(models_dir / str(existing.srdf), srdf_path)
        )
        if not (same_urdf and same_links and same_srdf):
            raise ValueError(
                f"robot {name!r} already exists ({path}) with another URDF, other links or "
                "another SRDF; "
                f"train it with --robot {name}, or pass --name to register this one apart"
            )
        return existing
    urdf_copy.parent.mkdir(parents=True, exist_ok=True)
    copy_meshes(urdf_path, urdf_copy.parent)
    if urdf_copy.resolve() != urdf_path.resolve():
        shutil.copyfile(urdf_path, urdf_copy)
    if srdf_path is not None and spec.srdf is not None:
        shutil.copyfile(srdf_path, models_dir / spec.srdf)
    path.write_text(spec.model_dump_json(indent=2) + "\n")
    return spec


def _same_content(path: Path, other: Path) -> bool:
    return path.is_file() and path.read_bytes() == other.read_bytes()


def copy_meshes(urdf_path: Path, directory: Path) -> None:
    """Copy the collision meshes `urdf_path` names by relative filenames to the same
    relative paths under `directory`, where a copy of the URDF finds them. A filename that
    leaves the URDF's directory ('..'), or a different file already at the copy's place,
    is refused by name."""
    for relative in mesh_references(urdf_path):
        source, copy = urdf_path.parent / relative, directory / relative
        if ".." in Path(relative).parts:
            raise ValueError(
                f"{urdf_path}: mesh {relative!r} lies outside the URDF's directory; give it "
                "by an absolute path, file:// or package://, or move it below the URDF"
            )
        if not source.is_file():
            raise ValueError(f"{urdf_path}: mesh {relative!r}: no file {source}")
        if copy.exists() and copy.read_bytes() != source.read_bytes():
            raise ValueError(f"mesh {relative!r}: {copy} exists with other content")
        if copy.resolve() != source.resolve():
            copy.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(source, copy)
