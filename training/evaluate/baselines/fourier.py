"""The paper's third baseline, "Fourier" (Clark and Xie, T-RO 2025), run with the
authors' own package `realtime-smm` 0.1.2, for the planar 3R only.

What realtime-smm does (read from its source; every step is its own code):

1. grid (`smm_grid.build_smm_grid`): targets on a line of the workspace, x in [0, 3] m at
   y = 0 (`use_xy_halfplane`: a target is rotated onto the +x axis and the rotation is
   added back to joint 1 after prediction). At each node it finds the SMM branches by
   random-restart IK and null-space continuation (`Robot.workspace_smms`: unit null
   vector plus a pseudo-inverse drift correction, step 0.05 rad, closed within 1.8
   steps of the start, resampled to 128 points); a node near a singular value (sigma_min
   <= 5e-3) or whose trace does not close is dropped;
2. clusters (`postprocess_grid`): neighbouring nodes with the same number of branches
   form a cluster (here rho < 1: 2 branches, 1 < rho < 3: 1), branches matched between
   neighbours;
3. networks (`learning.train_cluster_networks`): each branch's 128 points, mapped to the
   torus exp(jq), Fourier-transformed with the start fixed by the phase of the first
   harmonic and cut to the lowest 24 positive and negative frequencies; one MLP per
   cluster regresses those coefficients from the target (here only its distance rho)
   and a classifier MLP picks the cluster;
4. prediction (`SMMNetworkBundle.__call__`): classifier, the cluster's MLP, inverse DFT
   at any resolution; every branch is one component.

Budget: the paper's (seed appendix, "Fourier SMM" hyperparameters for the 3R) where the
0.1.2 API exposes it (`BUDGET`). Not exposed, so the library's defaults stand: its IK
restarts stop after 25 solutions without a new branch (paper: 40 IK seeds), the drift
correction is an undamped pseudo-inverse (paper: lambda 1e-3), the optimiser is Adam
with weight decay (paper: AdamW). The grid is not bit-reproducible: the library's worker
processes draw IK restarts from numpy's global generator in whatever order work arrives.

The robot is ours: `realtime_smm.Robot` with standard DH a = 1, 1, 1 m, alpha = d =
theta = 0 and revolute joints in [-pi, pi] has the FK of models/robots/planar3r.urdf
(checked by the tests against `references.planar3r`), and the library treats every
joint as periodic, as our model does.

Install. realtime-smm cannot be a pyproject dependency: it declares `tdqm`, a misspelling
of tqdm, which must never be installed. It is installed alone, after the project, by the
command of training/evaluate/packages.py (`no_deps_command`), and imported only where the
baseline runs: without it, this module's functions raise with that command.

Its real dependencies for what this module calls are numpy, scipy, torch and networkx
(the `train` extra; all pinned in constraints.txt), and tqdm, optional (progress bars).
It also declares zarr and platformdirs, which serve only its own disk cache
(`use_cache=True`, under the user's cache directory): this module keeps its model under
runs/fourier-planar3r/ and never needs them. Its `numpy>=2.3.3` is met by
our pin (2.4.6); it calls nothing numpy 1.26 lacks (read from its source). `pip check`
lists the three declared packages as missing: expected.

    smm-train baseline-fourier --train   # 5.8 min on 2 CPU cores

(measured while other jobs shared the 2 cores: 346 s wall, 3 min of CPU; grid 180 s,
networks 162 s, on one torch thread) (re)builds runs/fourier-planar3r/: bundle.pt, the
library's saved model, and training.json, the budget, clusters and wall times. The report
(training/evaluate/report.py) reuses it; without it, or without realtime-smm, the report
skips the rows and says why.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from service.manifest import Manifest
from service.models.registry import ServedModel
from service.pipeline.acceptance import accept
from service.pipeline.arrays import FloatArray
from service.pipeline.correction import correct, task_error_norms
from service.pipeline.joint_space import JointLimits
from service.pipeline.types import Tolerance
from training.evaluate.methods import MethodTarget, reference_target
from training.evaluate.packages import WITHOUT_DEPENDENCIES, missing_message, requiring

FOURIER = "Fourier (realtime-smm)"  # the raw prediction: every point of every branch
FOURIER_DLS = "Fourier (realtime-smm) + DLS"  # corrected and accepted like FM + DLS
VERSION = WITHOUT_DEPENDENCIES["realtime-smm"][0]  # the realtime-smm this module is written against
RUN_DIR = Path(__file__).resolve().parents[3] / "runs" / "fourier-planar3r"
PURPOSE = "The Fourier baseline (training/evaluate/baselines/fourier.py)"


@dataclass(frozen=True)
class Budget:
    """The paper's "Fourier SMM" hyperparameters for the 3R (seed appendix)."""

    # Grid: x in [0, 3] m (the half-plane line of the paper's [-3, 3] box) at 0.005 m.
    pos_resolution_m: float = 0.005
    # Tracing: 128 points per branch, step 0.05 rad, at most 1200 steps, singular below 5e-3.
    samples: int = 128
    step_rad: float = 0.05
    smm_iters: int = 1200
    sing_thresh: float = 5e-3
    # Networks: 6 x 150 leaky ReLU, 1500 epochs of batch 64, lr 1e-3, weight decay 1e-4.
    hidden_dims: tuple[int, ...] = (150,) * 6
    activation: str = "leaky_relu"
    epochs: int = 1500
    batch_size: int = 64
    learning_rate: float = 1e-3
    weight_decay: float = 1e-4
    # The lowest 24 positive and negative frequencies of the 128 kept.
    fft_cutoff: int = 24
    # Clusters of fewer nodes are not trained (paper: "min. cluster 8 nodes").
    min_cluster_nodes: int = 8
    # numpy's global generator (IK restarts, workspace limits) and torch's (weights).
    seed: int = 0


BUDGET = Budget()


class FourierUnavailable(RuntimeError):
    """The baseline cannot run here; the message says why (the report prints it)."""


@dataclass
class FourierModel:
    """A trained realtime-smm bundle (`SMMNetworkBundle`) and how it was trained."""

    bundle: Any  # realtime_smm.learning.SMMNetworkBundle
    training: dict[str, Any] = field(default_factory=dict)  # training.json

    @property
    def trace_samples(self) -> int:
        """Points per branch the networks were trained on (the fewest a prediction takes)."""
        return max(int(entry.spec.full_rows) for entry in self.bundle.clusters.values())


@dataclass(frozen=True)
class FourierSmm:
    """One prediction: every branch's points, labelled by branch."""

    q_rad: FloatArray  # (K, 3)
    branch: np.ndarray  # (K,) the branch (component) of each point
    wall_time_ms: float


def installed_version() -> str | None:
    try:
        return metadata.version("realtime-smm")
    except metadata.PackageNotFoundError:
        return None


def require_library() -> None:
    """Raise FourierUnavailable unless realtime-smm VERSION is importable."""
    version = installed_version()
    if version is None:
        raise FourierUnavailable(missing_message("realtime-smm", PURPOSE))
    if version != VERSION:
        raise FourierUnavailable(f"realtime-smm {version} installed; this baseline runs {VERSION}")


def supports(manifest: Manifest) -> str | None:
    """None when the baseline runs on this model, else why not."""
    if manifest.robot == "planar3r" and not manifest.task.orientation:
        return None
    if manifest.joints.count - manifest.task.dimension != 1:
        return "the Fourier series represents 1-D SMMs only"
    return (
        "run for the planar 3R only: realtime-smm 0.1.2 would grid the 3-D position x SO(3) "
        "pose space of a 7R (the paper: nearly 2 h with the authors' faster fork, about six "
        "times that with this code)"
    )


def planar3r_robot() -> Any:
    """Our planar 3R as a realtime_smm.Robot: unit links, standard DH, x-y position task."""
    with requiring("realtime-smm", PURPOSE):
        from realtime_smm import DHLink, JointType, Robot, TaskSpace

    links = [DHLink(a=1.0, alpha=0.0, d=0.0, theta=0.0, joint_type=JointType.REVOLUTE)] * 3
    return Robot(links, taskspace=TaskSpace.X | TaskSpace.Y)


def train(run_dir: Path = RUN_DIR, budget: Budget = BUDGET) -> FourierModel:
    """Grid, clusters and networks with realtime-smm's own code; saved under run_dir."""
    require_library()
    import torch

    np.random.seed(budget.seed)
    torch.manual_seed(budget.seed)
    threads = torch.get_num_threads()
    # One thread: batches of 64 through a 150-wide MLP gain nothing from a second, and on
    # a shared 2-core machine two spinning threads made each step 20x slower (measured).
    torch.set_num_threads(1)
    try:
        return _train(run_dir, budget)
    finally:
        torch.set_num_threads(threads)


def _train(run_dir: Path, budget: Budget) -> FourierModel:
    import torch

    with requiring("realtime-smm", PURPOSE):
        from realtime_smm import GridParams, SMMSolverParams, TrainingConfig
        from realtime_smm.helpers import SMMStatus
        from realtime_smm.learning import train_cluster_networks
        from realtime_smm.postprocess_grid import postprocess_grid
        from realtime_smm.smm_grid import build_smm_grid

    start = time.perf_counter()
    grid = build_smm_grid(
        planar3r_robot(),
        GridParams(pos_resolution=budget.pos_resolution_m, use_xy_halfplane=True),
        SMMSolverParams(
            samples=budget.samples, step=budget.step_rad,
            sing_thresh=budget.sing_thresh, smm_iters=budget.smm_iters,
        ),
        use_cache=False,
    )  # fmt: skip
    gridded = time.perf_counter()
    clusters = postprocess_grid(grid, use_cache=False)
    kept = [c for c in clusters if c.number_of_nodes() >= budget.min_cluster_nodes]
    clustered = time.perf_counter()
    bundle = train_cluster_networks(
        grid, kept, name=run_dir.name, output_root=run_dir.parent,
        config=TrainingConfig(
            epochs=budget.epochs, batch_size=budget.batch_size,
            learning_rate=budget.learning_rate, weight_decay=budget.weight_decay,
            hidden_dims=budget.hidden_dims, activation=budget.activation, device="cpu",
            fft_cutoff=budget.fft_cutoff,
        ),
    )  # fmt: skip
    trained = time.perf_counter()

    def described(cluster: Any) -> dict[str, Any]:
        rho = [float(np.linalg.norm(grid.graph.nodes[n]["T"][:2, 3])) for n in cluster.nodes]
        return {
            "nodes": cluster.number_of_nodes(),
            "branches": grid.get_node_smms(next(iter(cluster.nodes))).branches,
            "rho_m": [round(min(rho), 4), round(max(rho), 4)],
        }

    statuses = [grid.get_node_smms(n) for n in grid.graph.nodes]
    training = {
        "realtime_smm": VERSION,
        "budget": asdict(budget),
        "grid_nodes": grid.graph.number_of_nodes(),
        "nodes_ok": sum(s is not None and s.status == SMMStatus.OK for s in statuses),
        "clusters": [described(c) for c in kept],
        "clusters_dropped_nodes": [c.number_of_nodes() for c in clusters if c not in kept],
        "wall_time_s": {
            "grid": round(gridded - start, 1),
            "clusters": round(clustered - gridded, 1),
            "networks": round(trained - clustered, 1),
            "total": round(trained - start, 1),
        },
        "cpus": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "machine": platform.processor() or platform.machine(),
    }
    (run_dir / "training.json").write_text(json.dumps(training, indent=1) + "\n")
    return FourierModel(bundle, training)


def load(run_dir: Path = RUN_DIR) -> FourierModel:
    """The model `train` saved under run_dir; FourierUnavailable when there is none."""
    require_library()
    with requiring("realtime-smm", PURPOSE):
        from realtime_smm.learning import SMMNetworkBundle

    path = run_dir / "bundle.pt"
    if not path.is_file():
        raise FourierUnavailable(
            f"no trained model in {run_dir} (smm-train baseline-fourier --train)"
        )
    info = run_dir / "training.json"
    training = json.loads(info.read_text()) if info.is_file() else {}
    return FourierModel(SMMNetworkBundle.load(path=path, device="cpu"), training)


def load_for(manifest: Manifest, run_dir: Path = RUN_DIR) -> FourierModel:
    """The trained baseline for this model; FourierUnavailable (with why) when it cannot run."""
    reason = supports(manifest)
    if reason is not None:
        raise FourierUnavailable(reason)
    return load(run_dir)


def predict(model: FourierModel, target_xy: FloatArray, num_points: int) -> FourierSmm:
    """The SMM of a planar target (2,) as realtime-smm predicts it: `num_points` in all,
    split evenly over the predicted branches (at least the trained 128 per branch)."""
    start = time.perf_counter()
    pose = np.eye(4)
    pose[:2, 3] = target_xy
    bundle = model.bundle
    # How many branches the classifier picks (the first step of bundle.__call__, 0.1 ms),
    # so that the inverse DFT, most of the prediction's time, runs for num_points in all.
    features, _ = bundle._features_from_matrix(pose)
    branches = bundle.clusters[bundle._select_cluster(features)].spec.branches
    per_branch = max(-(-num_points // branches), model.trace_samples)
    smms = bundle(pose, samples=per_branch).data  # list of realtime_smm SMM, one per branch
    q = np.concatenate([np.zeros((0, 3))] + [s.angle.astype(np.float64) for s in smms])
    branch = np.repeat(np.arange(len(smms)), per_branch)
    return FourierSmm(q, branch, (time.perf_counter() - start) * 1e3)


def fourier_targets(
    model: ServedModel, fourier: FourierModel, q_target: np.ndarray, num_samples: int
) -> tuple[MethodTarget, MethodTarget]:
    """The raw prediction (every point returned, labelled by branch) and the same points
    after the service's DLS correction and acceptance (model defaults), branch labels kept:
    the FOURIER and FOURIER_DLS rows. The second's time includes the prediction."""
    manifest, defaults = model.manifest, model.manifest.defaults
    limits = JointLimits.of(manifest.joints)
    target, _ = reference_target(model, q_target)
    smm = predict(fourier, target.position_m, num_samples)
    raw_p, raw_o = task_error_norms(model.kinematics(smm.q_rad), target, manifest.task)
    raw = MethodTarget(
        raw_p, raw_o, smm.q_rad, raw_p, raw_o, smm.branch, len(smm.q_rad), smm.wall_time_ms,
        {"predict": smm.wall_time_ms, "total": smm.wall_time_ms},
    )  # fmt: skip
    start = time.perf_counter()
    task, steps = manifest.task, defaults.correction_steps
    correction = correct(smm.q_rad, target, task, model.kinematics, steps, defaults.damping, limits)
    corrected_s = time.perf_counter()
    kept = accept(correction, Tolerance.of(defaults), limits).accepted
    accepted_s = time.perf_counter()
    labels = np.unique(smm.branch[kept], return_inverse=True)[1]  # a branch lost is no component
    stages = {
        "predict": smm.wall_time_ms,
        "correct": (corrected_s - start) * 1e3,
        "accept": (accepted_s - corrected_s) * 1e3,
        "total": smm.wall_time_ms + (accepted_s - start) * 1e3,
    }
    corrected = MethodTarget(
        raw_p, raw_o, correction.q_rad[kept], correction.position_error_m[kept],
        correction.orientation_error_rad[kept], labels, len(smm.q_rad), stages["total"], stages,
    )  # fmt: skip
    return raw, corrected


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train baseline-fourier`."""
    parser.add_argument("--train", action="store_true", help=f"(re)build {RUN_DIR}")
    parser.add_argument("--run-dir", type=Path, default=RUN_DIR)


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train baseline-fourier --train`: train the baseline into --run-dir."""
    if not args.train:
        parser.error("nothing to do: pass --train")
    model = train(args.run_dir)
    print(json.dumps(model.training, indent=1))
