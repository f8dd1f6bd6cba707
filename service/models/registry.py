"""The model registry: every `models/<model-id>/manifest.json`, verified, with its ONNX sessions.

A model's kinematics is the numpy chain kernel on its chain.json when the manifest lists
one (checked against its kinematics.onnx at load), else kinematics.onnx itself (models
exported before chain.json existed). A model whose files are missing, whose sha256
differs from its manifest, or whose chain.json disagrees with its kinematics.onnx is not
served: the registry records it by name with the reason (naming the file), /readyz
reports it and does not claim readiness, and a request for it gets 503 saying why.
The other models are served. A models directory with no manifest at all stops
start-up. After start-up nothing is read from disk: no request field ever becomes a
path, a request only picks a loaded model out of a dictionary.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from service.errors import ModelUnavailableError, ModelVerificationError, UnknownModelError
from service.manifest import (
    CHAIN_FILE,
    COLLISION_FILE,
    FLOW_FILE,
    FLOW_FILES,
    FLOW_INT8_FILE,
    KINEMATICS_FILE,
    MANIFEST_FILE,
    REFLOW_INT8_FILE,
    ChainSpec,
    CollisionSpec,
    Manifest,
    SamplerSpec,
)
from service.models.chain import SerialChainKinematics
from service.models.int8_mlp import (
    SERVED_KERNELS,
    CompiledVelocityField,
    UnsupportedNetwork,
    best_kernel,
)
from service.models.sessions import OnnxKinematics, OnnxVelocityField, open_session
from service.pipeline.collision.robot import RobotSpheres
from service.pipeline.connect import find_coaxial_sets
from service.pipeline.joint_space import JointLimits
from service.pipeline.types import CoaxialSet, Kinematics, VelocityField

# chain.json against kinematics.onnx at load: configurations uniform in the joint limits
# (fixed seed), and the largest difference allowed over position, rotation and Jacobian.
# Both evaluate the same chain in float64: they agree to ~1e-15.
CHAIN_CHECK_CONFIGURATIONS = 256
CHAIN_CHECK_ATOL = 1e-10
INT8_FLOW_FILES = (FLOW_INT8_FILE, REFLOW_INT8_FILE)


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass(frozen=True)
class ServedModel:
    manifest: Manifest
    networks: dict[str, VelocityField]  # by file: every flow network the manifest lists
    kinematics: Kinematics  # SerialChainKinematics (chain.json) or OnnxKinematics
    limits: JointLimits  # the manifest's joint limits, as the pipeline's stages take them
    coaxial_sets: tuple[CoaxialSet, ...]  # where twin branches meet (connect/coaxial.py)
    robot_spheres: RobotSpheres | None  # collision.json's bodies; None without geometry
    version: str  # first 12 hex digits of the sha256 over the model's file digests
    row_threads: int = 1  # a compiled call's rows split over this many (pipeline/rows.py)

    def network(self, sampler: SamplerSpec) -> VelocityField:
        """The flow network `sampler` evaluates (its `flow` and `precision`)."""
        if sampler.file not in self.networks:
            raise ModelVerificationError(
                f"{self.manifest.model_id}: sampler flow {sampler.flow!r} in "
                f"{sampler.precision!r} has no network ({sampler.file}); choose from the "
                f"model's {sorted(self.networks)}"
            )
        return self.networks[sampler.file]

    @property
    def velocity(self) -> VelocityField:
        """The flow network of the default sampler."""
        return self.network(self.manifest.defaults.sampler)

    @property
    def reference(self) -> str:
        """`<model-id>@<version>`, as reported in every answer."""
        return f"{self.manifest.model_id}@{self.version}"


def _verify_file(path: Path, expected_sha256: str) -> None:
    if not path.is_file():
        raise ModelVerificationError(f"{path}: file listed in the manifest is missing")
    actual = sha256_of(path)
    if actual != expected_sha256:
        raise ModelVerificationError(
            f"{path}: sha256 {actual} does not match the manifest's {expected_sha256}"
        )


def chain_difference(chain: Kinematics, reference: Kinematics, manifest: Manifest) -> float:
    """Largest |chain - reference| over position, rotation and Jacobian, in the joint limits."""
    limits = JointLimits.of(manifest.joints)
    q = np.random.default_rng(0).uniform(
        limits.lower_rad, limits.upper_rad, (CHAIN_CHECK_CONFIGURATIONS, limits.count)
    )
    a, b = chain(q), reference(q)
    pairs = ((a.position_m, b.position_m), (a.rotation, b.rotation), (a.jacobian, b.jacobian))
    return max(float(np.max(np.abs(x - y))) for x, y in pairs)  # NaN if either has a NaN


def _load_chain(path: Path, manifest: Manifest, reference: Kinematics) -> SerialChainKinematics:
    """chain.json, refused unless it has the model's joints and agrees with kinematics.onnx."""
    chain = SerialChainKinematics.from_file(path)
    if chain.spec.joint_names != manifest.joints.names:
        raise ModelVerificationError(
            f"{path}: joints {chain.spec.joint_names} differ from the manifest's "
            f"{manifest.joints.names}"
        )
    difference = chain_difference(chain, reference, manifest)
    if not difference <= CHAIN_CHECK_ATOL:
        raise ModelVerificationError(
            f"{path}: differs from {KINEMATICS_FILE} by {difference:.3g} (largest over position, "
            f"rotation and Jacobian on {CHAIN_CHECK_CONFIGURATIONS} configurations in the "
            f"limits; at most {CHAIN_CHECK_ATOL:g} allowed)"
        )
    return chain


def _load_spheres(model_dir: Path, manifest: Manifest) -> RobotSpheres | None:
    """collision.json's bodies on chain.json's frames, when the manifest lists both."""
    if COLLISION_FILE not in manifest.files:
        return None
    if CHAIN_FILE not in manifest.files:
        raise ModelVerificationError(
            f"{model_dir / COLLISION_FILE}: needs {CHAIN_FILE} (the frames its bodies move with)"
        )
    path = model_dir / COLLISION_FILE
    try:
        spec = CollisionSpec.model_validate_json(path.read_bytes())
        chain = ChainSpec.model_validate_json((model_dir / CHAIN_FILE).read_bytes())
        return RobotSpheres.of(chain, spec)
    except (OSError, ValidationError, ValueError) as error:
        raise ModelVerificationError(f"{path}: unreadable collision model: {error}") from error


def threads_meant(threads: int) -> int:
    """The threads a `threads` setting gives a call: 0 means every core."""
    return threads or os.cpu_count() or 1


# What evaluates a model's flow network, as its "model loaded" log line names it.
ONNX_FLOW = "onnxruntime"


def compiled_flow(kernel: str) -> str:
    """The log's name of the compiled int8 layers on `kernel` ("amx", "avx2", ...)."""
    return f"compiled int8 layers ({kernel.upper()})"


def int8_on_compiled_layers() -> bool:
    """Whether this processor serves an int8 network on the compiled layers (with the
    setting on): where it has AMX, AVX-512 VNNI or AVX2 (int8_mlp.SERVED_KERNELS)."""
    return best_kernel() in SERVED_KERNELS


def int8_flow_here() -> str:
    """What evaluates an int8 flow network on this processor, with the setting on."""
    return compiled_flow(best_kernel()) if int8_on_compiled_layers() else ONNX_FLOW


def flow_kernel(velocity: VelocityField) -> str:
    """The name of what evaluates `velocity`: the compiled int8 layers or onnxruntime."""
    if isinstance(velocity, CompiledVelocityField):
        return compiled_flow(velocity.kernel)
    return ONNX_FLOW


def open_flow(path: Path, threads: int, serial: bool, compiled_int8: bool) -> VelocityField:
    """The flow network at `path`: an int8 one on the compiled layers (int8_mlp.py: the
    exact integer product on every processor) when `compiled_int8` and the processor
    has AMX, VNNI or AVX2, else onnxruntime's session (`threads`, and with `serial` a one-thread
    session beside it)."""
    if compiled_int8 and path.name in INT8_FLOW_FILES and int8_on_compiled_layers():
        try:
            return CompiledVelocityField.open(path, threads=threads_meant(threads))
        except UnsupportedNetwork:
            pass  # a network of other layers: onnxruntime runs any
    return OnnxVelocityField.open(path, threads, serial=serial)


def load_model(model_dir: Path, threads: int, compiled_int8: bool = True) -> ServedModel:
    """Read, verify and open one model directory."""
    manifest_path = model_dir / MANIFEST_FILE
    try:
        manifest = Manifest.model_validate_json(manifest_path.read_bytes())
    except (OSError, ValidationError) as error:
        raise ModelVerificationError(f"{manifest_path}: unreadable manifest: {error}") from error
    for required in (FLOW_FILE, KINEMATICS_FILE, manifest.defaults.sampler.file):
        if required not in manifest.files:
            raise ModelVerificationError(f"{manifest_path}: does not list {required}")
    for name, expected in sorted(manifest.files.items()):
        _verify_file(model_dir / name, expected)
    _verify_file(model_dir.parent / manifest.urdf.path, manifest.urdf.sha256)
    combined = "".join(f"{name}:{sha}\n" for name, sha in sorted(manifest.files.items()))
    limits = JointLimits.of(manifest.joints)
    onnx_kinematics = OnnxKinematics(open_session(model_dir / KINEMATICS_FILE, threads))
    kinematics: Kinematics = onnx_kinematics
    if CHAIN_FILE in manifest.files:
        kinematics = _load_chain(model_dir / CHAIN_FILE, manifest, onnx_kinematics)
    return ServedModel(
        manifest=manifest,
        networks={
            # A one-thread session (each holds its weights: ~45 MiB over the seven
            # bundled models' every network) only beside the network the requests use.
            name: open_flow(
                model_dir / name,
                threads,
                serial=name == manifest.defaults.sampler.file,
                compiled_int8=compiled_int8,
            )
            for name in FLOW_FILES.values()
            if name in manifest.files
        },
        kinematics=kinematics,
        limits=limits,
        coaxial_sets=tuple(find_coaxial_sets(kinematics, limits)),
        robot_spheres=_load_spheres(model_dir, manifest),
        version=hashlib.sha256(combined.encode()).hexdigest()[:12],
        # The network's threads (0: onnxruntime's default, every core) for the rows too.
        row_threads=threads_meant(threads),
    )


@dataclass(frozen=True)
class FailedModel:
    """A model directory that failed verification at start-up, and why."""

    name: str  # the directory name, which is the model id
    reason: str
    robot: str | None = None  # known when the manifest itself was readable
    task: str | None = None


def _read_identity(model_dir: Path) -> tuple[str | None, str | None]:
    """(robot, task) from a manifest that may fail full validation; (None, None) if unreadable."""
    try:
        raw = json.loads((model_dir / MANIFEST_FILE).read_bytes())
        return str(raw["robot"]), str(raw["task"]["name"])
    except (OSError, ValueError, KeyError, TypeError):
        return None, None


class Registry:
    """Served models keyed by (robot, task), and the ones that failed verification."""

    def __init__(self, models: list[ServedModel], failed: list[FailedModel] | None = None) -> None:
        self._models: dict[tuple[str, str], ServedModel] = {
            (m.manifest.robot, m.manifest.task.name): m for m in models
        }
        self.failed: list[FailedModel] = sorted(failed or [], key=lambda f: f.name)

    @classmethod
    def load(cls, models_dir: Path, threads: int = 0, compiled_int8: bool = True) -> Registry:
        """Load every directory of `models_dir` that holds a manifest (hidden ones excepted).

        A directory that fails verification is recorded in `failed`, not raised; only a
        `models_dir` with no manifest at all raises ModelVerificationError.
        """
        directories = sorted(
            p.parent
            for p in models_dir.glob(f"*/{MANIFEST_FILE}")
            if not p.parent.name.startswith(".")
        )
        if not directories:
            raise ModelVerificationError(f"{models_dir}: no */{MANIFEST_FILE} found")
        models, failed = [], []
        for directory in directories:
            try:
                models.append(load_model(directory, threads, compiled_int8))
            except ModelVerificationError as error:
                robot, task = _read_identity(directory)
                # Paths relative to the models directory: the reason is shown to clients.
                reason = str(error).replace(f"{models_dir}/", "")
                failed.append(FailedModel(directory.name, reason, robot, task))
        return cls(models, failed)

    def get(self, robot: str, task: str) -> ServedModel:
        try:
            return self._models[(robot, task)]
        except KeyError:
            pass
        for failure in self.failed:
            if (failure.robot, failure.task) == (robot, task):
                raise ModelUnavailableError(
                    f"model {failure.name} ({robot}, {task}) failed verification at start-up and "
                    f"is not served: {failure.reason}"
                )
        raise UnknownModelError(robot, task, sorted(self._models))

    def all(self) -> list[ServedModel]:
        return [self._models[key] for key in sorted(self._models)]

    @property
    def ready(self) -> bool:
        """Every model found was loaded and verified."""
        return not self.failed
