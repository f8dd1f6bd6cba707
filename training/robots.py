"""The robots and tasks the project trains: each is data (URDF, end effector, task axes, reach)."""

from __future__ import annotations

from dataclasses import dataclass

from service.manifest import TaskSpec


@dataclass(frozen=True)
class RobotSpec:
    name: str
    urdf: str  # relative to the models directory
    end_effector_link: str
    reach_m: float  # L of the paper: errors are reported in % of it
    tasks: dict[str, TaskSpec]

    def task(self, name: str) -> TaskSpec:
        try:
            return self.tasks[name]
        except KeyError:
            raise ValueError(
                f"unknown task {name!r} for robot {self.name!r}; choose from {sorted(self.tasks)}"
            ) from None


ROBOTS: dict[str, RobotSpec] = {
    "planar3r": RobotSpec(
        name="planar3r",
        urdf="robots/planar3r.urdf",
        end_effector_link="ee",
        reach_m=3.0,
        tasks={"position": TaskSpec(name="position", position_axes=[0, 1], orientation=False)},
    ),
    "iiwa14": RobotSpec(
        name="iiwa14",
        urdf="robots/iiwa14.urdf",
        end_effector_link="ee",
        reach_m=1.2,
        tasks={
            "pose": TaskSpec(name="pose", position_axes=[0, 1, 2], orientation=True),
            "position": TaskSpec(name="position", position_axes=[0, 1, 2], orientation=False),
        },
    ),
}


def robot_spec(name: str) -> RobotSpec:
    try:
        return ROBOTS[name]
    except KeyError:
        raise ValueError(f"unknown robot {name!r}; choose from {sorted(ROBOTS)}") from None
