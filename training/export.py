"""Export a trained flow and the robot's kinematics, check parity, write the manifest.

The kinematics go out twice from the same pytorch-kinematics chain: kinematics.onnx (the
traced FK and Jacobian) and chain.json (the chain as data, for the service's numpy
kernel). Parity is checked on random inputs: onnxruntime and the numpy kernel must
reproduce torch (flow in float32, kinematics in float64) or the export fails loudly and
nothing is left half-written. The flow also goes out in int8 (training/quantise.py, with
its own guard); the sweep decides which of the two serves. `refresh_kinematics`
re-exports only the kinematics of an existing model directory (its flow untouched).
"""

from __future__ import annotations

import datetime as dt
import logging
import shutil
import warnings
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

from service.manifest import (
    CHAIN_FILE,
    COLLISION_FILE,
    FLOW_FILE,
    FLOW_INT8_FILE,
    KINEMATICS_FILE,
    MANIFEST_FILE,
    ChainSpec,
    CollisionRecord,
    ConditionSpec,
    Defaults,
    FileRef,
    JointSpec,
    Manifest,
    RawError,
    TaskSpec,
    TrainingRecord,
)
from service.models.chain import SerialChainKinematics
from service.models.registry import load_model, sha256_of
from service.models.sessions import FLOW_INPUTS, FLOW_OUTPUT, KINEMATICS_INPUT, KINEMATICS_OUTPUTS
from service.pipeline.joint_space import JointLimits
from service.pipeline.targets import condition_names
from training.checkpoint import TrainResult
from training.collision.record import CollisionSettings, write_collision
from training.config import TrainConfig
from training.data import FlowData
from training.defaults import serving_defaults
from training.evaluate.judge import REPORT_TARGETS
from training.evaluate.quality import measure_quality
from training.kinematics import (
    ForwardKinematics,
    chain_spec,
    joint_spec,
    load_chain,
    measured_reach_m,
)
from training.model import VelocityField
from training.quantise import quantise_flow
from training.robots import RobotSpec
from training.staging import staged_copy
from training.sweep import AXES, Axis, judged_sweep, sweep_defaults

# float32 network: torch and onnxruntime sum each layer's products in another order, so
# they differ by float32 rounding of the activations a row carries (~1e-6 relative), and
# an output row is compared at its own scale, its largest |output|: off the data (the
# check's inputs), a row can hold velocities in the thousands beside one of about 1,
# which that rounding moves by ~1e-3 (a reflowed iiwa14 pose flow: 1.8e-3 at |output| 2
# in a row reaching 2.5e3, 8.6e-6 of it). A wrong network is off by its output's size.
FLOW_PARITY_ATOL = 1e-4
FLOW_PARITY_RTOL = 1e-5
KINEMATICS_PARITY_ATOL = 1e-10  # float64; observed ~1e-15
CHAIN_PARITY_ATOL = 1e-12  # float64, the same chain evaluated in another order; observed ~1e-15


class ExportParityError(RuntimeError):
    """onnxruntime disagrees with torch on the exported graph."""


def _quiet_exporter() -> None:
    # torch.onnx logs a warning per missing torchvision op and pytorch-kinematics trips a
    # dynamo lru_cache warning; neither concerns these graphs, and parity is checked below.
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    warnings.filterwarnings("ignore", module=r"torch\.(onnx|_dynamo|export)")
    warnings.filterwarnings("ignore", category=FutureWarning)


def _export(
    module: torch.nn.Module,
    inputs: tuple[torch.Tensor, ...],
    path: Path,
    input_names: list[str],
    output_names: list[str],
) -> None:
    _quiet_exporter()
    batch = torch.export.Dim("batch", min=1)
    torch.onnx.export(
        module,
        inputs,
        str(path),
        dynamo=True,
        input_names=input_names,
        output_names=output_names,
        dynamic_shapes=tuple({0: batch} for _ in inputs),
        external_data=False,  # one self-contained file per network
        verbose=False,
    )


def export_flow(model: VelocityField, path: Path, joint_dim: int, condition_dim: int) -> None:
    model = model.cpu().eval()
    example = (torch.zeros(4, joint_dim), torch.zeros(4, 1), torch.zeros(4, condition_dim))
    _export(model, example, path, list(FLOW_INPUTS), [FLOW_OUTPUT])
    check_flow_parity(model, path, joint_dim, condition_dim)


def check_flow_parity(model: VelocityField, path: Path, joint_dim: int, condition_dim: int) -> None:
    """Raise ExportParityError unless onnxruntime on `path` reproduces `model`."""
    generator = torch.Generator().manual_seed(0)
    q_t = torch.randn(257, joint_dim, generator=generator)
    t = torch.rand(257, 1, generator=generator)
    condition = torch.rand(257, condition_dim, generator=generator) * 2 - 1
    with torch.no_grad():
        expected = model(q_t, t, condition).numpy()
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (actual,) = session.run(
        [FLOW_OUTPUT], {"q_t": q_t.numpy(), "t": t.numpy(), "condition": condition.numpy()}
    )
    if not np.max(flow_parity_excess(actual, expected)) <= 0:
        error = float(np.max(np.abs(actual - expected)))
        raise ExportParityError(
            f"{path}: flow differs from torch by up to {error:.3g}, beyond "
            f"atol {FLOW_PARITY_ATOL} + rtol {FLOW_PARITY_RTOL} x the row's largest "
            "|torch output|"
        )


def flow_parity_excess(actual: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """(B, n): how far each output of onnxruntime (`actual`, (B, n)) is from torch's
    beyond the bound, atol + rtol x the largest |output| of its row; <= 0 is within."""
    scale = np.max(np.abs(expected), axis=1, keepdims=True)  # (B, 1)
    return np.abs(actual - expected) - (FLOW_PARITY_ATOL + FLOW_PARITY_RTOL * scale)


def export_kinematics(fk: ForwardKinematics, path: Path, joints: JointSpec) -> None:
    example = torch.zeros(4, joints.count, dtype=torch.float64)
    fk = fk.eval()
    _export(fk, (example,), path, [KINEMATICS_INPUT], list(KINEMATICS_OUTPUTS))
    check_kinematics_parity(fk, path, joints)


def check_kinematics_parity(fk: ForwardKinematics, path: Path, joints: JointSpec) -> None:
    """Raise ExportParityError unless onnxruntime on `path` reproduces pytorch-kinematics."""
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])

    def onnx(q: np.ndarray) -> list[np.ndarray]:
        return list(session.run(list(KINEMATICS_OUTPUTS), {KINEMATICS_INPUT: q}))

    _check_against_torch(fk, joints, onnx, path, "kinematics", KINEMATICS_PARITY_ATOL)


def _check_against_torch(
    fk: ForwardKinematics,
    joints: JointSpec,
    evaluate: Callable[[np.ndarray], Sequence[np.ndarray]],
    path: Path,
    what: str,
    atol: float,
) -> None:
    """Raise ExportParityError unless `evaluate` (q (B, n) -> position, rotation, Jacobian)
    reproduces pytorch-kinematics within `atol` on configurations uniform in the limits."""
    limits = JointLimits.of(joints)
    q = np.random.default_rng(0).uniform(
        limits.lower_rad, limits.upper_rad, size=(257, joints.count)
    )
    with torch.no_grad():
        expected = [x.numpy() for x in fk(torch.from_numpy(q))]
    for name, a, e in zip(KINEMATICS_OUTPUTS, evaluate(q), expected, strict=True):
        error = float(np.max(np.abs(a - e)))
        if not error <= atol:
            raise ExportParityError(
                f"{path}: {what} output {name!r} differs from pytorch-kinematics by "
                f"{error:.3g} > {atol}"
            )


def export_chain(fk: ForwardKinematics, path: Path, joints: JointSpec) -> None:
    """Write the chain as chain.json; raise ExportParityError unless it reproduces `fk`."""
    spec = chain_spec(fk.chain)
    if spec.joint_names != joints.names:
        raise ExportParityError(f"{path}: chain joints {spec.joint_names} are not {joints.names}")
    path.write_text(spec.model_dump_json(indent=2) + "\n")
    check_chain_parity(fk, path, joints)


def check_chain_parity(fk: ForwardKinematics, path: Path, joints: JointSpec) -> None:
    """Raise ExportParityError unless the numpy kernel on `path` reproduces pytorch-kinematics."""
    kernel = SerialChainKinematics.from_file(path)

    def chain(q: np.ndarray) -> list[np.ndarray]:
        answer = kernel(q)
        return [answer.position_m, answer.rotation, answer.jacobian]

    _check_against_torch(fk, joints, chain, path, "chain", CHAIN_PARITY_ATOL)


def export_model(
    model_dir: Path,
    models_dir: Path,
    robot: RobotSpec,
    task: TaskSpec,
    joints: JointSpec,
    fk: ForwardKinematics,
    data: FlowData,
    config: TrainConfig,
    result: TrainResult,
    command: str,
    code_commit: str,
    export_commit: str | None = None,
    processor: dict[str, object] | None = None,
) -> Manifest:
    """Write flow.onnx, flow_int8.onnx, kinematics.onnx, chain.json, collision.json (when
    the URDF has collision geometry on the chain: `training.collision`, with the robot
    file's SRDF) and manifest.json into `model_dir`; choose the serving defaults (the
    sweep) and measure.

    The manifest's reach L is measured on the chain (`measured_reach_m`: the farthest the
    end effector gets from the base-link origin within the limits), not typed in.

    Everything is written to a hidden staging directory beside `model_dir` (the registry
    skips hidden directories) and moved into place only once parity and quality are done,
    so a failed export never leaves a half-written model behind.
    """
    staging = model_dir.with_name(f".{model_dir.name}.staging")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    export_flow(result.model, staging / FLOW_FILE, joints.count, data.condition.shape[1])
    quantise_flow(staging / FLOW_FILE, staging / FLOW_INT8_FILE)
    export_kinematics(fk, staging / KINEMATICS_FILE, joints)
    export_chain(fk, staging / CHAIN_FILE, joints)
    commit = export_commit or code_commit
    collision = _write_collision(staging, models_dir, robot, fk, joints, command, commit)
    files = [FLOW_FILE, FLOW_INT8_FILE, KINEMATICS_FILE, CHAIN_FILE]
    files += [] if collision is None else [COLLISION_FILE]
    model_id = f"{robot.name}-{task.name}"
    manifest = Manifest(
        model_id=model_id,
        robot=robot.name,
        task=task,
        urdf=FileRef(path=robot.urdf, sha256=sha256_of(models_dir / robot.urdf)),
        end_effector_link=robot.end_effector_link,
        reach_m=measured_reach_m(fk.chain, joints),
        joints=joints,
        joint_normalisation=data.joint_normalisation,
        condition=ConditionSpec(
            names=condition_names(task), normalisation=data.condition_normalisation
        ),
        files={name: sha256_of(staging / name) for name in files},
        defaults=serving_defaults(model_id, task, joints.count - task.dimension),
        training=TrainingRecord(
            command=command,
            samples=config.samples,
            epochs=config.epochs,
            batch_size=config.batch_size,
            device=config.device if config.device != "cuda" else torch.cuda.get_device_name(),
            wall_time_s=round(result.wall_time_s, 1),
            best_validation_loss=result.best_validation_loss,
            best_epoch=result.best_epoch,
            torch_version=torch.__version__,
            git_commit=code_commit,
            export_git_commit=None if export_commit == code_commit else export_commit,
            config=config.as_dict(),
            processor=processor,
        ),
        collision=collision,
        created_utc=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
    )
    (staging / MANIFEST_FILE).write_text(manifest.model_dump_json(indent=2) + "\n")
    manifest = sweep_and_measure(
        staging, manifest, config.threads, config.sweep_targets, config.sweep_seed,
        config.eval_targets, config.eval_samples_per_target, config.eval_seed,
    )  # fmt: skip
    shutil.rmtree(model_dir, ignore_errors=True)
    staging.rename(model_dir)
    return manifest


def _write_collision(
    model_dir: Path, models_dir: Path, robot: RobotSpec, fk: ForwardKinematics,
    joints: JointSpec, command: str, commit: str,
) -> CollisionRecord | None:  # fmt: skip
    """collision.json of the robot's URDF (with its robot file's SRDF) for the exported
    chain, and its record; None when the URDF has no collision geometry on the chain."""
    srdf = None if robot.srdf is None else models_dir / robot.srdf
    return write_collision(
        model_dir, models_dir, models_dir / robot.urdf, chain_spec(fk.chain), joints,
        CollisionSettings(srdf_path=srdf), command, commit,
    )  # fmt: skip


def sweep_and_measure(
    model_dir: Path, manifest: Manifest, threads: int, sweep_targets: int, sweep_seed: int,
    eval_targets: int, eval_samples_per_target: int, eval_seed: int,
    axes: Sequence[Axis] = AXES, paper_row: RawError | None = None,
    incumbent: Defaults | None = None, judge_targets: int = REPORT_TARGETS,
) -> Manifest:  # fmt: skip
    """Choose the serving defaults (the sweep over `axes`; none with 0 targets) and measure
    quality on exactly what ships, the model in `model_dir` loaded as the service loads it;
    each step written into its manifest. `paper_row`: the paper sampler's raw errors
    already measured on the same network and targets (`measure_quality`). `incumbent`:
    the defaults served until now; the swept ones replace them only if judged no worse
    against the exact SMMs on `judge_targets` report targets (training/sweep/
    `judged_sweep`)."""
    manifest_path = model_dir / MANIFEST_FILE
    served = load_model(model_dir, threads=threads)
    if sweep_targets > 0:

        def progress(line: str) -> None:
            print(f"[{manifest.model_id}] {line}", flush=True)

        if incumbent is None:
            defaults = sweep_defaults(
                served, sweep_targets, sweep_seed, axes=axes, progress=progress
            ).defaults
        else:
            defaults = judged_sweep(
                served, sweep_targets, sweep_seed, incumbent, progress=progress, axes=axes,
                judge_targets=judge_targets,
            )  # fmt: skip
        manifest = manifest.model_copy(update={"defaults": defaults})
        manifest_path.write_text(manifest.model_dump_json(indent=2) + "\n")
        served = replace(served, manifest=manifest)
    quality = measure_quality(
        served, eval_targets, eval_samples_per_target, eval_seed, paper_row=paper_row
    )
    manifest = manifest.model_copy(update={"quality": quality})
    manifest_path.write_text(manifest.model_dump_json(indent=2) + "\n")
    return manifest


def refresh_kinematics(model_dir: Path, models_dir: Path, threads: int = 1) -> Manifest:
    """Re-export kinematics.onnx and chain.json of an existing model; its flow is untouched.

    The chain is loaded from the URDF the manifest names, which must still have the
    manifest's sha256 and give the manifest's joints (the flow was trained on that arm).
    Both files are parity-checked against pytorch-kinematics, the manifest's `files`
    digests are rewritten (chain.json added) and nothing else in it changes. The work is
    done on a hidden copy of the directory, loaded as the service loads it, and swapped
    in only when that succeeds.
    """
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    urdf_path = models_dir / manifest.urdf.path
    if sha256_of(urdf_path) != manifest.urdf.sha256:
        raise ExportParityError(
            f"{urdf_path}: sha256 differs from the manifest's; the flow was trained on the "
            "recorded URDF, so its kinematics cannot be refreshed from this one (retrain)"
        )
    # The chain starts where the model's did: chain.json's base link (a model from before
    # chain.json was trained from the URDF's root).
    base_link = None
    if CHAIN_FILE in manifest.files:
        base_link = ChainSpec.model_validate_json((model_dir / CHAIN_FILE).read_bytes()).base_link
    fk = ForwardKinematics(load_chain(urdf_path, manifest.end_effector_link, base_link))
    joints = joint_spec(fk.chain)
    if joints != manifest.joints:
        raise ExportParityError(f"{urdf_path}: joints {joints} differ from the manifest's")
    with staged_copy(model_dir) as staging:
        export_kinematics(fk, staging / KINEMATICS_FILE, joints)
        export_chain(fk, staging / CHAIN_FILE, joints)
        names = [*manifest.files, *([] if CHAIN_FILE in manifest.files else [CHAIN_FILE])]
        manifest = manifest.model_copy(
            update={"files": {name: sha256_of(staging / name) for name in names}}
        )
        # exclude_unset: fields the schema gained since this manifest was written stay absent
        (staging / MANIFEST_FILE).write_text(
            manifest.model_dump_json(indent=2, exclude_unset=True) + "\n"
        )
        load_model(staging, threads=threads)  # verifies sha256 and chain.json vs kinematics.onnx
    return manifest
