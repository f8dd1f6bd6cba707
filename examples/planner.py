"""A planner's use of the service: from where the arm is, where to go for a new pose.

The arm (KUKA iiwa14, the bundled `iiwa14-pose` model) holds configuration q and must
reach a new target pose in a scene: a table it stands on and a shelf (a board above the
target and a panel beside it), sent as the request's `obstacles` with a 1 cm margin. The
service answers every way of reaching the target that is free of the scene and of the
arm itself; this script then

1. takes the component nearest to q (`reference_configuration = q`: the service reports
   each component's `distance_to_reference` and the member nearest to q), because the
   arm can reach that component with the least joint motion;
2. within it, picks the safest configuration: the one of greatest clearance from the
   scene and from the arm itself (`safest_configuration`, with `clearance_m` the least
   along the component), because that leaves the most room for the motion that brings
   the arm there. With `--objective limit-margin` it picks instead the configuration
   with the largest joint-limit margin (the smallest distance of any joint to its limit,
   limits from GET /robots; ties, as on this pose where q4 is the same on the whole
   component, broken by the next-smallest margin, compared to 1e-6 rad);
3. for a 1-D component (r = 1), walks the component's ordered `path` from the point
   nearest to q to that configuration and reports the walk's length in the joint metric:
   the self-motion that keeps the end effector on the target while the arm moves there,
   every point of it clear of the scene;
4. asks the service for that motion itself (POST /smm/self-motion, from the point
   nearest to q to the choice, in the same scene): exact configurations at most 0.05 rad
   apart, which a controller can follow.

Runs with the client's dependencies only (httpx, pydantic; no numpy):

    python examples/planner.py --url http://127.0.0.1:8000

`--json PATH` also writes the request, the choice and the figures, for a program (the
tests check the choice against the service's answer and an independent FK).
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

from service.client import (
    CollisionIn,
    ComponentOut,
    GoalIn,
    ObstacleIn,
    QuaternionIn,
    RobotOut,
    SelfMotionRequest,
    SmmClient,
    SmmClientError,
    SmmRequest,
    TargetIn,
)

Configuration = list[float]

# Where the arm is, and the pose it is asked to reach (the iiwa14 pose example of docs/examples.md:
# made by a configuration 0.33 rad from this q, so its nearest component is close by).
DEFAULT_Q = [0.0, 0.5, 0.0, -1.4, 0.0, 1.0, 0.0]
DEFAULT_POSITION = [0.6501, 0.2011, 0.5018]
DEFAULT_ORIENTATION = [0.2165, -0.1458, 0.9648, 0.0327]  # w, x, y, z
# The scene, in the arm's base frame (m): a table whose top is the base's floor, and a
# shelf around the target, a board 0.3 m above it and a panel 0.4 m to its side.
TABLE = ObstacleIn(shape="box", dimensions=[1.2, 1.2, 0.04], position=[0.4, 0.0, -0.02])
SHELF_BOARD = ObstacleIn(shape="box", dimensions=[0.4, 0.8, 0.03], position=[0.65, 0.2, 0.8])
SHELF_PANEL = ObstacleIn(shape="box", dimensions=[0.4, 0.03, 0.8], position=[0.65, -0.2, 0.4])
SCENE = [TABLE, SHELF_BOARD, SHELF_PANEL]
MARGIN_M = 0.01


def joint_distance(a: Sequence[float], b: Sequence[float], periodic: Sequence[bool]) -> float:
    """The service's joint metric: Euclidean over joints, a periodic joint's difference
    wrapped to (-pi, pi]."""
    total = 0.0
    for qa, qb, wraps in zip(a, b, periodic, strict=True):
        d = qa - qb
        if wraps:
            d = math.remainder(d, 2 * math.pi)
        total += d * d
    return math.sqrt(total)


def margins(q: Sequence[float], robot: RobotOut) -> list[tuple[float, int]]:
    """(distance to the nearer limit in rad, joint index) of every limited joint, smallest
    first. Periodic joints have no limit and do not count."""
    return sorted(
        (min(value - lower, upper - value), index)
        for index, (value, lower, upper, wraps) in enumerate(
            zip(q, robot.joint_lower, robot.joint_upper, robot.periodic_joints, strict=True)
        )
        if not wraps
    )


def margin_key(q: Sequence[float], robot: RobotOut) -> tuple[float, ...]:
    """Larger is better: the smallest margin first, then the next (leximin), each rounded
    to 1e-6 rad so that a joint constant on the component ties instead of deciding by its
    rounding noise."""
    return tuple(round(m, 6) for m, _ in margins(q, robot))


def walk_length(
    path: Sequence[Configuration], start: int, end: int, closed: bool, periodic: Sequence[bool]
) -> tuple[float, int]:
    """(length in rad, steps) of the walk along `path` from index `start` to `end`; on a
    closed loop, the shorter way round."""

    def run(indices: Sequence[int]) -> float:
        return sum(
            joint_distance(path[i], path[j], periodic) for i, j in itertools.pairwise(indices)
        )

    lo, hi = sorted((start, end))
    forward = list(range(lo, hi + 1))
    best = (run(forward), len(forward) - 1)
    if closed:
        around = [*range(hi, len(path)), *range(lo + 1)]  # hi .. last, first .. lo
        best = min(best, (run(around), len(around) - 1))
    return best


def nearest_index(
    points: Sequence[Configuration], q: Sequence[float], periodic: Sequence[bool]
) -> int:
    return min(range(len(points)), key=lambda i: joint_distance(points[i], q, periodic))


@dataclass
class Choice:
    component_id: int
    distance_to_reference_rad: float  # from q to the component's nearest member
    components: int
    objective: str  # "clearance" or "limit-margin": what chose the configuration
    configuration: Configuration
    source: str  # "safest_configuration", "configurations" or "path": where it was found
    clearance_m: float | None  # the component's least clearance along it
    safest_clearance_m: float | None  # the clearance of its safest configuration
    ends: list[str] | None  # why an open component ends (joint_limit or collision)
    margin_rad: float  # the smallest joint-limit margin of the choice
    limiting_joint: str
    margins_rad: dict[str, float]  # every limited joint's margin, smallest first
    nearest_margins_rad: dict[str, float]  # the same for the member nearest to q
    max_position_error_m: float
    max_orientation_error_rad: float
    path_length_rad: float | None  # None: not a 1-D component with a path
    path_steps: int | None
    path_from_index: int | None
    path_to_index: int | None
    closed: bool | None


def choose(component: ComponentOut, components: int, robot: RobotOut, objective: str) -> Choice:
    """The safest (or largest-margin) configuration of `component`, and the walk to it
    along its path."""
    periodic = robot.periodic_joints
    if objective == "clearance" and component.safest_configuration is not None:
        best_q, source = component.safest_configuration, "safest_configuration"
    else:
        objective = "limit-margin"
        candidates = [(q, "configurations") for q in component.configurations]
        candidates += [(q, "path") for q in component.path or []]
        best_q, source = max(candidates, key=lambda c: margin_key(c[0], robot))
    assert component.nearest_to_reference is not None  # the request gives a reference

    def named(q: Sequence[float]) -> dict[str, float]:
        return {robot.joint_names[i]: m for m, i in margins(q, robot)}

    chosen = named(best_q)
    length = steps = start = end = None
    if component.path:
        start = nearest_index(component.path, component.nearest_to_reference, periodic)
        end = nearest_index(component.path, best_q, periodic)
        length, steps = walk_length(component.path, start, end, bool(component.closed), periodic)
    return Choice(
        component_id=component.id,
        distance_to_reference_rad=component.distance_to_reference or 0.0,
        components=components,
        objective=objective,
        configuration=best_q,
        source=source,
        clearance_m=component.clearance_m,
        safest_clearance_m=component.safest_clearance_m,
        ends=None if component.ends is None else list(component.ends),
        margin_rad=next(iter(chosen.values())),
        limiting_joint=next(iter(chosen)),
        margins_rad=chosen,
        nearest_margins_rad=named(component.nearest_to_reference),
        max_position_error_m=component.max_position_error,
        max_orientation_error_rad=component.max_orientation_error,
        path_length_rad=length,
        path_steps=steps,
        path_from_index=start,
        path_to_index=end,
        closed=component.closed,
    )


def rounded(q: Sequence[float]) -> str:
    return "[" + ", ".join(f"{v:.4f}" for v in q) + "]"


def listed(margins_rad: dict[str, float]) -> str:
    return ", ".join(f"{name} {m:.4f}" for name, m in margins_rad.items())


def print_choice(choice: Choice) -> None:
    """The choice, its clearance and margins, the walk to it, and why."""
    print(f"choice:  {rounded(choice.configuration)} (the component's {choice.source})")
    if choice.clearance_m is not None:
        print(
            f"clear:   {choice.safest_clearance_m:.4f} m here, at least "
            f"{choice.clearance_m:.4f} m anywhere along the component"
        )
    print(f"margins: {listed(choice.margins_rad)} rad to the nearer limit, smallest first")
    print(f"         (the member nearest to q: {listed(choice.nearest_margins_rad)})")
    print(
        f"         reaches the target within {choice.max_position_error_m:.1e} m and "
        f"{choice.max_orientation_error_rad:.1e} rad (the component's largest errors)"
    )
    if choice.path_length_rad is not None:
        shape = "a closed loop" if choice.closed else f"its ends: {', '.join(choice.ends or [])}"
        print(
            f"walk:    along the component's path ({shape}) from point {choice.path_from_index} "
            f"(nearest to q) to point {choice.path_to_index}: {choice.path_length_rad:.4f} rad "
            f"in {choice.path_steps} steps, the end effector on the target throughout"
        )
    within = (
        "the greatest clearance leaves the most room from the scene and the arm itself"
        if choice.objective == "clearance"
        else "the largest smallest margin (ties broken by the next) leaves the most room "
        "before a joint limit"
    )
    print(
        f"why:     the nearest component needs the least joint motion to enter; within it, {within}"
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", default="http://127.0.0.1:8000")
    parser.add_argument("--api-key", default=None, help="the server's SMM_API_KEY, if set")
    parser.add_argument("--q", type=float, nargs=7, default=DEFAULT_Q, help="rad")
    parser.add_argument("--position", type=float, nargs=3, default=DEFAULT_POSITION, help="m")
    parser.add_argument(
        "--orientation",
        type=float,
        nargs=4,
        default=DEFAULT_ORIENTATION,
        metavar=("W", "X", "Y", "Z"),
    )
    parser.add_argument("--num-samples", type=int, default=None, help="default: the model's")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--objective",
        choices=("clearance", "limit-margin"),
        default="clearance",
        help="what picks the configuration within the nearest component",
    )
    parser.add_argument("--no-scene", action="store_true", help="send no obstacles")
    parser.add_argument("--json", type=Path, default=None, help="also write the choice here")
    args = parser.parse_args(argv)

    w, x, y, z = args.orientation
    request = SmmRequest(
        robot="iiwa14",
        task="pose",
        target=TargetIn(position=args.position, orientation=QuaternionIn(w=w, x=x, y=y, z=z)),
        num_samples=args.num_samples,
        seed=args.seed,
        reference_configuration=args.q,
        obstacles=[] if args.no_scene else SCENE,
        collision=CollisionIn(check_self=True, margin_m=MARGIN_M),
    )
    try:
        with SmmClient(args.url, api_key=args.api_key) as client:
            robot = client.robot("iiwa14", "pose")
            answer = client.smm(request)
    except SmmClientError as error:
        print(f"the service failed: {error}", file=sys.stderr)
        return 1
    print(f"q now:   {rounded(args.q)}")
    print(f"target:  position {args.position} m, orientation (w, x, y, z) {args.orientation}")
    if answer.status == "no_solution":
        print(f"no configuration reaches the target within the limits ({answer.counts})")
        return 2

    nearest = min(answer.components, key=lambda c: c.distance_to_reference or 0.0)
    choice = choose(nearest, len(answer.components), robot, args.objective)
    others = sorted(c.distance_to_reference or 0.0 for c in answer.components if c is not nearest)
    runner_up = f"the next {others[0]:.4f} rad" if others else "the only one"
    print(
        f"service: {len(answer.components)} components ({answer.model}); the nearest to q is "
        f"component {choice.component_id}, {choice.distance_to_reference_rad:.4f} rad away "
        f"({runner_up})"
    )
    print(
        f"scene:   {answer.collision.obstacles} obstacles, self-collision "
        f"{'checked' if answer.collision.self_checked else 'not checked'}, margin "
        f"{answer.collision.margin_m} m; {answer.counts.rejected_collision} samples in collision"
    )
    print_choice(choice)
    # The motion itself, from the component's point nearest q to the choice.
    motion_request = SelfMotionRequest(
        robot=request.robot,
        task=request.task,
        target=request.target,
        start=nearest.nearest_to_reference or nearest.representative,
        goal=GoalIn(configuration=choice.configuration),
        num_samples=request.num_samples,
        seed=request.seed,
        obstacles=request.obstacles,
        collision=request.collision,
    )
    try:
        with SmmClient(args.url, api_key=args.api_key) as client:
            motion = client.self_motion(motion_request)
    except SmmClientError as error:
        print(f"the service failed: {error}", file=sys.stderr)
        return 1
    if motion.status == "ok" and motion.path is not None:
        print(
            f"motion:  POST /smm/self-motion: {len(motion.path)} configurations at most 0.05 rad "
            f"apart, {motion.length_rad:.4f} rad, from the point nearest q to the choice"
        )
    elif motion.status == "not_connected":
        print(f"motion:  {motion.status}: the choice is not on the start's component")
    else:
        print(f"motion:  {motion.status}: no motion at 0.05 rad along the component's roadmap")
    if args.json is not None:
        record = {
            "request": request.model_dump(mode="json"),
            "choice": asdict(choice),
            "motion_request": motion_request.model_dump(mode="json", by_alias=True),
            "motion": motion.model_dump(mode="json", include={"status", "path", "length_rad"}),
        }
        args.json.write_text(json.dumps(record, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
