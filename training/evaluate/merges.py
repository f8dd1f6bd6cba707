"""Is a reported merge real? A check of the reference, not of the service.

A merge is a returned component whose configurations lie on two or more counted reference
components. Either the service joined two components that are apart, or the reference
split one (the 4-D references decide components by a link radius on a grid). For each
merge and each pair of its reference components, the closest pair of the returned
component's configurations across the two is joined by the projected local planner (the
service's own, `service/pipeline/connect/local_planner.py`) at a fine step: every step projected
onto the fibre to within `PROJECTION_TOLERANCE`, inside the limits, no step longer than
2 x delta; where that straight path fails (the fibre bends away from the segment, or a
limit cuts across it), by the steer at the same step (`steering.py`: along the part of
the direction to b the fibre allows, sliding along the limit faces). Where the returned
component has a roadmap (r > 1), the way the service itself took is walked too: the
shortest chain of its roadmap's edges from a node on one reference component to a node
on the other, every edge walked again the same two ways (the service walked it at its
connectivity step, 0.3 rad on a 4-D fibre, projected to 1e-4, and takes a last hop of up
to that step as it is). Where any of these holds, the two reference components are one:
the reference split it. Where all fail, the merge stays unsettled (a longer way round may
still join them), and the first roadmap edge refused is measured (`refused_edge_rad`).
On a target the answer flags near a singular value neither is decided: twin strands of
the fibre run closer there than a walk's step resolves (on the iiwa14 pose's target 177
a fine straight walk joins two exact closed-form arcs), so a walk is no witness.

    smm-train merges --model panda-position   # every merge of its report
    smm-train merges --model panda-position --targets 2 19 29

The targets are the report's (`training.evaluate.report`: the FK of configurations uniform
in the limits, seed 7, and the answer with the same sample seed), so a merge the report
lists is the merge checked here.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, dataclass
from itertools import combinations, pairwise
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.connect import PlannerSettings, SteerSettings, edges_on_fibre, steer
from service.pipeline.fibre import Fibre
from service.pipeline.joint_space import JointLimits
from service.pipeline.space import FibreSpace
from service.pipeline.types import ComponentRoadmap, Tolerance
from training.checkout import git_commit
from training.evaluate.methods import (
    MethodTarget,
    flow_target,
    reference_target,
    served_roadmaps,
)
from training.evaluate.metrics import counted_components, exact_labels
from training.evaluate.report import REPORTS_DIR
from training.evaluate.targets import uniform_configurations
from training.evaluate.truth import Truth, ground_truth

DELTA_RAD = 0.003  # the planner's step: 1/17 of OMPL's 0.05
PROJECTION_TOLERANCE = 1e-6  # the contract's tolerance, 100x tighter than OMPL's 1e-4
REPORT_SEED = 7  # the report's targets
REPORT_TARGETS = 200


@dataclass(frozen=True)
class MergeCheck:
    target: int
    returned_component: int
    reference_components: tuple[int, int]
    shares: tuple[float, float]  # of the fibre (4-D) or arc lengths in rad (1-D)
    gap_rad: float  # joint distance of the closest pair across the two
    joined: bool  # a straight projected path joins the pair on the fibre
    steered: bool = False  # the fine steer joins it (tried where the straight path fails)
    # The service's roadmap (None: the component has none): the edges of its shortest
    # chain across the two, and whether every one holds at the fine step.
    roadmap_edges: int | None = None
    roadmap_joined: bool | None = None
    refused_edge_rad: float | None = None  # the first refused edge's length
    # The answer flags the target near a singular value: twin strands of the fibre may
    # run closer there than a walk's step resolves, so a walk may cross between them.
    near_singular: bool = False

    @property
    def one_component(self) -> bool:
        """The pair is joined on the fibre: straight, steered or along the service's
        roadmap."""
        return self.joined or self.steered or bool(self.roadmap_joined)


def space_of(model: ServedModel, q_target: FloatArray) -> FibreSpace:
    """The fibre of the target that q_target (n,) reaches inside the model's limits, as
    the service projects onto it. Its walks do not test the coaxial sets (a step across
    one off the fibre is not refused): the check walks as the committed reports measured
    it."""
    target, _ = reference_target(model, q_target)
    manifest = model.manifest
    return FibreSpace(
        fibre=Fibre(target, manifest.task, model.kinematics, manifest.defaults.damping),
        limits=JointLimits.of(manifest.joints),
        coaxial_sets=(),
        tolerance=Tolerance.of(manifest.defaults),
        collision=CollisionCheck.none(),
    )


def joined_on_fibre(
    space: FibreSpace,
    q_a_rad: FloatArray,  # (n,)
    q_b_rad: FloatArray,  # (n,)
    delta_rad: float = DELTA_RAD,
) -> bool:
    """Whether the straight projected path from a to b holds at step `delta_rad`."""
    settings = PlannerSettings(
        delta_rad=delta_rad,
        lambda_=2.0,
        projection_tolerance=PROJECTION_TOLERANCE,
        projection_iterations=3,
        extra_iterations=6,
    )
    reached = edges_on_fibre(space, q_a_rad[None], q_b_rad[None], settings)
    return bool(reached[0])


# A fine steer gives up where the distance to b has not shrunk by STALL_PROGRESS_RAD over
# the last STALL_STEPS steps (0.3 rad of walking at the fine step).
STALL_STEPS = 100
STALL_PROGRESS_RAD = 0.01


def steered_on_fibre(
    space: FibreSpace,
    q_a_rad: FloatArray,  # (n,)
    q_b_rad: FloatArray,  # (n,)
    step_rad: float = DELTA_RAD,
) -> bool:
    """Whether the steer (`service/pipeline/connect/steering.py`: along the part of the
    direction to b that the fibre allows, sliding along the limit faces) gets from a to
    within `step_rad` of b at steps of `step_rad`, each projected to
    PROJECTION_TOLERANCE: a path on the fibre inside the limits that need not follow the
    straight segment."""
    chord = float(space.limits.distance(q_a_rad[None], q_b_rad[None])[0])
    settings = SteerSettings(
        step_rad=step_rad,
        max_steps=int(np.ceil(3.0 * chord / step_rad)) + 2,
        lambda_=2.0,
        projection_tolerance=PROJECTION_TOLERANCE,
        projection_iterations=6,
        stall_steps=STALL_STEPS,
        min_progress_rad=STALL_PROGRESS_RAD,
    )
    return bool(steer(space, q_a_rad[None], q_b_rad[None], settings).arrived[0])


def walked_on_fibre(
    space: FibreSpace, q_a_rad: FloatArray, q_b_rad: FloatArray, step_rad: float = DELTA_RAD
) -> bool:
    """a and b (n,) joined on the fibre at the fine step: straight, or else by the steer."""
    return joined_on_fibre(space, q_a_rad, q_b_rad, step_rad) or steered_on_fibre(
        space, q_a_rad, q_b_rad, step_rad
    )


@dataclass(frozen=True)
class RoadmapWalk:
    """The service's roadmap chain between two reference components, walked finely."""

    edges: int  # in the chain
    joined: bool  # every edge held
    refused_edge_rad: float | None  # the first edge that did not, its length


def roadmap_walk(
    space: FibreSpace,
    roadmap: ComponentRoadmap,
    exact: IntArray,  # (M,) each node's reference component
    a: int,
    b: int,
    delta_rad: float = DELTA_RAD,
) -> RoadmapWalk | None:
    """The shortest chain of the roadmap's edges (by joint length) from a node on reference
    component `a` to one on `b`, every edge walked again at `delta_rad` (`walked_on_fibre`:
    straight, or else steered); None when no node lies on one of them."""
    nodes, edges = roadmap.q_rad, roadmap.edges
    starts, ends = np.flatnonzero(exact == a), np.flatnonzero(exact == b)
    if not len(starts) or not len(ends) or not len(edges):
        return None
    lengths = space.limits.distance(nodes[edges[:, 0]], nodes[edges[:, 1]])  # (E,)
    graph = coo_matrix(
        (lengths + 1e-12, (edges[:, 0], edges[:, 1])), shape=(len(nodes), len(nodes))
    ).tocsr()
    distance, previous, _ = dijkstra(
        graph, directed=False, indices=starts, return_predecessors=True, min_only=True
    )
    end = ends[int(np.argmin(distance[ends]))]
    if not np.isfinite(distance[end]):
        return None
    chain = [int(end)]
    while previous[chain[-1]] >= 0:
        chain.append(int(previous[chain[-1]]))
    for i, j in pairwise(chain[::-1]):
        if not walked_on_fibre(space, nodes[i], nodes[j], delta_rad):
            length = float(space.limits.distance(nodes[i][None], nodes[j][None])[0])
            return RoadmapWalk(len(chain) - 1, False, length)
    return RoadmapWalk(len(chain) - 1, True, None)


def check_merges(
    model: ServedModel,
    index: int,
    q_target: FloatArray,
    answer: MethodTarget,
    truth: Truth,
    delta_rad: float = DELTA_RAD,
    roadmaps: list[ComponentRoadmap | None] | None = None,
) -> list[MergeCheck]:
    """Every merge of `answer` against `truth`, each checked on the fibre: straight, and
    along the service's roadmap where `roadmaps` gives the component's (in label order)."""
    assert answer.labels is not None and truth.size is not None
    counted = counted_components(truth)
    exact = exact_labels(answer.returned, truth)  # (K,)
    space = space_of(model, q_target)
    checks = []
    for component in np.unique(answer.labels).tolist():
        mine = answer.labels == component
        on = [int(c) for c in np.unique(exact[mine]) if counted[c]]
        roadmap = None if roadmaps is None else roadmaps[component]
        # The roadmap with each node's reference component, where there is one.
        labelled = None if roadmap is None else (roadmap, exact_labels(roadmap.q_rad, truth))
        for a, b in combinations(on, 2):
            side_a = answer.returned[mine & (exact == a)]
            side_b = answer.returned[mine & (exact == b)]
            _, nearest = cKDTree(side_b).query(side_a)  # (A,) Euclidean candidates
            gaps = space.limits.distance(side_a, side_b[nearest])
            i = int(np.argmin(gaps))
            q_a, q_b = side_a[i], side_b[nearest[i]]
            joined = joined_on_fibre(space, q_a, q_b, delta_rad)
            steered = not joined and steered_on_fibre(space, q_a, q_b, delta_rad)
            walk = None if labelled is None else roadmap_walk(space, *labelled, a, b, delta_rad)
            checks.append(
                MergeCheck(
                    target=index,
                    returned_component=component,
                    reference_components=(a, b),
                    shares=(float(truth.size[a]), float(truth.size[b])),
                    gap_rad=float(gaps[i]),
                    joined=joined,
                    steered=steered,
                    roadmap_edges=None if walk is None else walk.edges,
                    roadmap_joined=None if walk is None else walk.joined,
                    refused_edge_rad=None if walk is None else walk.refused_edge_rad,
                    near_singular=bool(answer.near_singular),
                )
            )
    return checks


def report_target(model: ServedModel, index: int, num_samples: int = 1000) -> list[MergeCheck]:
    """The merges of the report's target `index`, checked."""
    limits = model.limits
    q_target = uniform_configurations(limits, REPORT_TARGETS, REPORT_SEED)[index]
    truth = ground_truth(model, q_target, REPORT_SEED + index)
    answer = flow_target(model, q_target, num_samples, seed=index)
    roadmaps = served_roadmaps(model, q_target, num_samples, seed=index)
    return check_merges(model, index, q_target, answer, truth, roadmaps=roadmaps)


def settled(checks: list[MergeCheck]) -> bool:
    """Whether one merge's reference components are all one by the pairs joined, straight
    or along the service's roadmap (True: the reference split a component; False:
    unsettled)."""
    nodes = sorted({c for check in checks for c in check.reference_components})
    index = {node: i for i, node in enumerate(nodes)}
    pairs = [
        tuple(index[c] for c in check.reference_components)
        for check in checks
        if check.one_component
    ]
    rows, cols = [a for a, _ in pairs], [b for _, b in pairs]
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(nodes), len(nodes)))
    return bool(connected_components(graph, directed=False)[0] == 1)


def merge_targets(model_id: str) -> list[int]:
    """The targets the committed report lists with merges."""
    report = json.loads((REPORTS_DIR / f"{model_id}.json").read_text())
    return [t["index"] for t in report.get("wrong_count_targets", []) if t.get("merges")]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train merges`."""
    parser.add_argument("--model", required=True, help="a model id under models/")
    parser.add_argument(
        "--targets", type=int, nargs="+", help="report indices (default: every one the "
        "committed report lists with merges)",
    )  # fmt: skip
    parser.add_argument(
        "--out", type=Path, help="write the record here (docs/reports/merges/<model>.json "
        "for the committed one)",
    )  # fmt: skip


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train merges`: every merge of the report's targets, and how many settle."""
    del parser
    commit = git_commit()
    model = load_model(REPO_MODELS_DIR / args.model, threads=1)
    merges: list[dict[str, object]] = []
    for index in args.targets or merge_targets(args.model):
        by_component: dict[int, list[MergeCheck]] = {}
        for check in report_target(model, index):
            print(json.dumps(asdict(check)))
            by_component.setdefault(check.returned_component, []).append(check)
        for component, checks in by_component.items():
            flagged = any(check.near_singular for check in checks)
            merges.append(
                {
                    "target": index,
                    "returned_component": component,
                    "near_singular": flagged,
                    "reference_split": not flagged and settled(checks),
                    "pairs": [asdict(check) for check in checks],
                }
            )
    reference_splits = sum(bool(merge["reference_split"]) for merge in merges)
    undecided = sum(bool(merge["near_singular"]) for merge in merges)
    unsettled = len(merges) - reference_splits - undecided
    print(
        f"{len(merges)} merges: {reference_splits} reference splits (every reference "
        "component of the merge joined on the fibre: straight, steered or along the "
        f"service's roadmap), {unsettled} unsettled, {undecided} on targets flagged "
        "near-singular (not decided: a walk may cross between twin strands there)"
    )
    if args.out is not None:
        command = f"smm-train merges --model {args.model}"
        if args.targets:
            command += " --targets " + " ".join(str(t) for t in args.targets)
        record = {
            "command": f"{command} --out {args.out}",
            "git_commit": commit,
            "model": model.reference,
            "delta_rad": DELTA_RAD,
            "projection_tolerance": PROJECTION_TOLERANCE,
            "merges": len(merges),
            "reference_splits": reference_splits,
            "unsettled": unsettled,
            "near_singular": undecided,
            "checks": merges,
        }
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(record, indent=1) + "\n")
