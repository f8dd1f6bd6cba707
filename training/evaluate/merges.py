"""Is a reported merge real? A check of the reference, not of the service.

A merge is a returned component whose configurations lie on two or more counted reference
components. Either the service joined two components that are apart, or the reference
split one (the 4-D references decide components by a link radius on a grid). For each
merge and each pair of its reference components, the closest pair of the returned
component's configurations across the two is joined by the projected local planner (the
service's own, `service/pipeline/connect/local_planner.py`) at a fine step: every step projected
onto the fibre to within `PROJECTION_TOLERANCE`, inside the limits, no step longer than
2 x delta. Where that straight path holds, the two reference components are one: the
reference split it. Where it fails, the merge stays unsettled (a longer way round may
still join them).

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
from itertools import combinations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from service.manifest import REPO_MODELS_DIR
from service.models.registry import ServedModel, load_model
from service.pipeline.arrays import FloatArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.connect import PlannerSettings, edges_on_fibre
from service.pipeline.fibre import Fibre
from service.pipeline.joint_space import JointLimits
from service.pipeline.space import FibreSpace
from service.pipeline.types import Tolerance
from training.evaluate.methods import MethodTarget, flow_target, reference_target
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


def check_merges(
    model: ServedModel,
    index: int,
    q_target: FloatArray,
    answer: MethodTarget,
    truth: Truth,
    delta_rad: float = DELTA_RAD,
) -> list[MergeCheck]:
    """Every merge of `answer` against `truth`, each checked on the fibre."""
    assert answer.labels is not None and truth.size is not None
    counted = counted_components(truth)
    exact = exact_labels(answer.returned, truth)  # (K,)
    space = space_of(model, q_target)
    checks = []
    for component in np.unique(answer.labels).tolist():
        mine = answer.labels == component
        on = [int(c) for c in np.unique(exact[mine]) if counted[c]]
        for a, b in combinations(on, 2):
            side_a = answer.returned[mine & (exact == a)]
            side_b = answer.returned[mine & (exact == b)]
            _, nearest = cKDTree(side_b).query(side_a)  # (A,) Euclidean candidates
            gaps = space.limits.distance(side_a, side_b[nearest])
            i = int(np.argmin(gaps))
            q_a, q_b = side_a[i], side_b[nearest[i]]
            checks.append(
                MergeCheck(
                    target=index,
                    returned_component=component,
                    reference_components=(a, b),
                    shares=(float(truth.size[a]), float(truth.size[b])),
                    gap_rad=float(gaps[i]),
                    joined=joined_on_fibre(space, q_a, q_b, delta_rad),
                )
            )
    return checks


def report_target(model: ServedModel, index: int, num_samples: int = 1000) -> list[MergeCheck]:
    """The merges of the report's target `index`, checked."""
    limits = model.limits
    q_target = uniform_configurations(limits, REPORT_TARGETS, REPORT_SEED)[index]
    truth = ground_truth(model, q_target, REPORT_SEED + index)
    answer = flow_target(model, q_target, num_samples, seed=index)
    return check_merges(model, index, q_target, answer, truth)


def settled(checks: list[MergeCheck]) -> bool:
    """Whether one merge's reference components are all one by the joined pairs (True: the
    reference split a component; False: unsettled)."""
    nodes = sorted({c for check in checks for c in check.reference_components})
    index = {node: i for i, node in enumerate(nodes)}
    pairs = [
        tuple(index[c] for c in check.reference_components) for check in checks if check.joined
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


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train merges`: every merge of the report's targets, and how many settle."""
    del parser
    model = load_model(REPO_MODELS_DIR / args.model, threads=1)
    reference_splits = unsettled = 0
    for index in args.targets or merge_targets(args.model):
        by_component: dict[int, list[MergeCheck]] = {}
        for check in report_target(model, index):
            print(json.dumps(asdict(check)))
            by_component.setdefault(check.returned_component, []).append(check)
        for checks in by_component.values():
            split = settled(checks)
            reference_splits += split
            unsettled += not split
    print(
        f"{reference_splits + unsettled} merges: {reference_splits} reference splits (every "
        f"reference component of the merge joined by straight projected paths), {unsettled} "
        "unsettled"
    )
