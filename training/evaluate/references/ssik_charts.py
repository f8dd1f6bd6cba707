"""ssik's closed-form self-motion charts as components: the analytic peer the benchmark times.

ssik (8.2, BSD-3, personalrobotics/ssik) gives the 1-D self-motion manifold of an SRS or
spherical-shoulder 7R arm at a full pose in closed form: `Manipulator.self_motion(T)`
returns every IK branch as a chart q(t), `Chart.in_limits` cuts its domain to the joint
box exactly, and `Chart.sample` places points along the in-limit arcs uniformly in arc
length. One connected piece of the fibre inside the limits can come back as arcs of
several charts (a branch ends where another begins, at a fold of the chart's coordinate),
so arcs whose ends meet (within `GLUE_RAD`) are glued into one component. What this takes
for a target, from the pose to the components with points at the path spacing, is what a
planner would pay to get from ssik what the service answers.

Frames: ssik's prebuilt iiwa14 ends where the bundled one does; its Panda ends at the
flange, `PANDA_TOOL` from the bundled Panda's end effector (the hand's frame, 0.1034 m
further and turned 45 degrees about z), so a bundled pose T is asked of ssik as
T PANDA_TOOL (tests/training/evaluate/test_ssik_charts.py checks both against the
bundled chains' FK).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np

from service.pipeline.arrays import FloatArray, IntArray

# The bundled Panda's end effector (the hand) to ssik's Panda end (the flange): 0.1034 m
# back along z, turned 45 degrees about z.
PANDA_TOOL = np.array(
    [
        [np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0],
        [np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0],
        [0.0, 0.0, 1.0, -0.1034],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
# ssik's prebuilt arm for each bundled robot it covers, and the tool it adds to our flange.
ARMS: dict[str, tuple[str, FloatArray]] = {
    "iiwa14": ("iiwa14_ik", np.eye(4)),
    "panda": ("franka_panda_ik", PANDA_TOOL),
}
# Arc ends closer than this (joint metric, rad) are one point of the fibre: the arcs join.
# At a fold the closed form is exact only to about 1e-7 (ssik's Chart.q).
GLUE_RAD = 1e-5


@dataclass(frozen=True)
class ChartComponents:
    """The in-limit arcs of every chart, glued into components."""

    q_rad: FloatArray  # (P, 7) points along the arcs, at most about `spacing_rad` apart
    component: IntArray  # (P,) the component of each point, 0..C-1
    arcs: int  # in-limit arcs before gluing
    charts_ms: float  # the charts and their in-limit intervals: ssik's closed-form answer
    points_ms: float  # then the points along the arcs, and the gluing


def supported(robot: str) -> bool:
    """Whether ssik has the robot's arm (and ssik is installed)."""
    if robot not in ARMS:
        return False
    try:
        import ssik  # noqa: F401
    except ImportError:
        return False
    return True


@cache
def manipulator(robot: str) -> Any:
    """ssik's prebuilt arm for a bundled robot (made once: building it costs ~0.1 s)."""
    import ssik

    return ssik.Manipulator.from_prebuilt(ARMS[robot][0])


def chart_components(
    robot: str,
    pose: FloatArray,  # (4, 4) the bundled chain's end effector, base frame
    lower_rad: FloatArray,  # (7,)
    upper_rad: FloatArray,  # (7,)
    spacing_rad: float,
) -> ChartComponents:
    """Every in-limit arc of ssik's charts at `pose`, sampled at `spacing_rad` (joint
    metric, uniform in arc length), glued where arcs meet."""
    arm = manipulator(robot)
    limits = np.stack([lower_rad, upper_rad], axis=1)  # (7, 2)
    # ssik's angles are unwrapped along a chart (a joint may read q + 2 pi): each is read
    # in the 2 pi window centred on its limits.
    low = 0.5 * (lower_rad + upper_rad) - np.pi

    def window(q: FloatArray) -> FloatArray:
        return low + np.mod(q - low, 2.0 * np.pi)

    start = time.perf_counter()
    manifold = arm.self_motion(pose @ ARMS[robot][1])
    arcs = [(chart, arc) for chart in manifold.charts for arc in chart.in_limits(limits)]
    # Each arc's ends, exact (the closed form at the interval's ends): arcs of two charts
    # meet at a fold of their coordinate, where the points sampled along them stop short.
    ends = [window(chart.q(np.array(arc))) for chart, arc in arcs]  # (2, 7) each
    component = _glued(ends)
    charted = time.perf_counter()
    pieces: list[FloatArray] = []
    labels: list[IntArray] = []
    for chart in {id(chart): chart for chart, _ in arcs}.values():
        count = max(2, int(np.ceil(chart.length(limits=limits) / spacing_rad)))
        for _, unwrapped in chart.sample(count, limits=limits):
            if len(unwrapped):
                # An arc ends on a limit to ssik's bisection tolerance (up to ~4e-8 rad
                # past it, measured): its end point is put on the limit.
                qs = np.clip(window(unwrapped), lower_rad, upper_rad)
                pieces.append(qs)
                labels.append(np.full(len(qs), component[_arc_of(arcs, chart, qs)]))
    done = time.perf_counter()
    points = np.concatenate(pieces) if pieces else np.zeros((0, 7))
    label = np.concatenate(labels) if labels else np.zeros(0, dtype=np.int64)
    return ChartComponents(
        points, label.astype(np.int64), len(arcs), (charted - start) * 1e3, (done - charted) * 1e3
    )


def _arc_of(arcs: list[tuple[Any, tuple[float, float]]], chart: Any, qs: FloatArray) -> int:
    """The arc of `chart` that a sampled piece lies on: the one whose middle point is
    nearest the piece's middle point."""
    middle = qs[len(qs) // 2]
    mine = [i for i, (c, _) in enumerate(arcs) if c is chart]
    gaps = [np.linalg.norm(np.cos(chart.q(0.5 * sum(arcs[i][1])) - middle) - 1.0) for i in mine]
    return mine[int(np.argmin(gaps))]


def _glued(ends: list[FloatArray]) -> IntArray:
    """(A,) the component of each arc (its two ends (2, 7)): arcs join where an end of one
    is within GLUE_RAD of an end of another (union-find), numbered by first arc."""
    parent = list(range(len(ends)))

    def root(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    points = [(a, end) for a, pair in enumerate(ends) for end in pair]
    for i, (a, p) in enumerate(points):
        for b, other in points[i + 1 :]:
            if a != b and np.linalg.norm(p - other) <= GLUE_RAD:
                parent[root(a)] = root(b)
    roots = [root(a) for a in range(len(ends))]
    numbering: dict[int, int] = {}
    return np.array([numbering.setdefault(r, len(numbering)) for r in roots], dtype=np.int64)
