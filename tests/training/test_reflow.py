"""reflow: few-step sampling learned from the base flow's own endpoints, resumable, served.

- The torch module rebuilt from flow.onnx's weights is the exported network: onnxruntime
  on flow.onnx gives the same velocities.
- The teacher pairs are the service's sampler: integrating flow.onnx in onnxruntime with
  the service's integrator from the same noise lands on the same endpoints.
- Training straightens the paths: on held-out pairs the one-step endpoint moves towards
  the teacher's, against the base flow's one-step endpoint (the conditional mean).
- A run stopped mid-way continues with resume to the weights of a run never stopped.
- The export lists reflow.onnx and reflow_int8.onnx with their record; the service serves
  the reflowed sampler, and its one-step answers reach the target by the planar arm's
  closed-form FK; a manifest asking for a reflow the directory lacks is refused by name.
- The paper sampler's raw errors are reused only when measured on the same targets and
  samples (the reflow leaves the base flow as it was).
- --export-only refuses a model without a reflow by naming the command that trains one,
  keeps the committed reflow.onnx and the commit it was trained at, and records its own.
"""

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest
import torch

import training.reflow as reflow
from service.errors import ModelVerificationError
from service.manifest import (
    FLOW_FILE,
    MANIFEST_FILE,
    REFLOW_FILE,
    REFLOW_INT8_FILE,
    Manifest,
    SamplerSpec,
)
from service.models.registry import load_model
from service.pipeline.run import run
from service.pipeline.sampling import euler_integrate
from service.pipeline.types import Query
from tests.support.app import PLANAR3R_DIR
from tests.support.tiny_training import weights_equal
from training.evaluate.references.planar3r import planar3r_position
from training.evaluate.served import with_defaults

SMALL = reflow.ReflowConfig(
    pairs=3000, validation_pairs=500, teacher_steps=8, steps=60, batch_size=256,
    learning_rate=1e-3, threads=1, autocast_bf16=False, validate_every=20,
)  # fmt: skip


def _planar_copy(tmp_path: Path) -> Path:
    """A copy of the bundled planar model (and its robots/) without any reflow."""
    models = tmp_path / "models"
    shutil.copytree(PLANAR3R_DIR.parent / "robots", models / "robots")
    model_dir = models / PLANAR3R_DIR.name
    shutil.copytree(PLANAR3R_DIR, model_dir)
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    for name in (REFLOW_FILE, REFLOW_INT8_FILE):
        (model_dir / name).unlink(missing_ok=True)
    files = {k: v for k, v in manifest.files.items() if k not in (REFLOW_FILE, REFLOW_INT8_FILE)}
    sampler = manifest.defaults.sampler.model_copy(update={"flow": "base"})
    manifest = manifest.model_copy(
        update={
            "files": files,
            "reflow": None,
            "defaults": manifest.defaults.model_copy(update={"sampler": sampler}),
        }
    )
    (model_dir / MANIFEST_FILE).write_text(manifest.model_dump_json(indent=2))
    return model_dir


def test_the_module_rebuilt_from_flow_onnx_is_the_exported_network() -> None:
    model = reflow.base_flow(PLANAR3R_DIR)
    rng = np.random.default_rng(3)
    q_t = rng.standard_normal((300, 3), dtype=np.float32)
    t = rng.uniform(0, 1, (300, 1)).astype(np.float32)
    condition = rng.uniform(-1, 1, (300, 2)).astype(np.float32)
    session = ort.InferenceSession(str(PLANAR3R_DIR / FLOW_FILE))
    (expected,) = session.run(None, {"q_t": q_t, "t": t, "condition": condition})
    actual = reflow.numpy_field(model)(q_t, t, condition)
    np.testing.assert_allclose(actual, expected, rtol=1e-5, atol=1e-4)
    assert np.abs(expected).max() > 0.1  # a trained field, not zeros


def test_teacher_pairs_are_the_services_sampler_from_the_same_noise() -> None:
    config = replace(SMALL, pairs=200, validation_pairs=56)
    pairs = reflow.teacher_pairs(PLANAR3R_DIR, reflow.base_flow(PLANAR3R_DIR), config)
    assert pairs.z.shape == pairs.q_1.shape == (256, 3) and pairs.condition.shape == (256, 2)
    served = load_model(PLANAR3R_DIR, threads=1)
    onnx_flow = served.network(SamplerSpec(steps=1, precision="float32"))
    expected = euler_integrate(
        onnx_flow, pairs.z.numpy(), pairs.condition.numpy(), config.teacher_steps,
        time_power=config.teacher_time_power,
    )  # fmt: skip
    np.testing.assert_allclose(pairs.q_1.numpy(), expected, atol=1e-3)
    # The conditions are the arm's own reachable positions, normalised into [-1, 1].
    assert pairs.condition.abs().max() <= 1.0 + 1e-6
    assert float((pairs.q_1 - pairs.z).norm(dim=1).mean()) > 0.5  # the flow moved them


def test_training_moves_the_one_step_endpoint_towards_the_teachers(tmp_path: Path) -> None:
    student, state = reflow.train_reflow(PLANAR3R_DIR, tmp_path / "run", SMALL, resume=False)
    pairs = reflow.TeacherPairs(**torch.load(tmp_path / "run" / reflow.PAIRS_FILE))
    validation = reflow.TeacherPairs(
        *(x[SMALL.pairs :] for x in (pairs.z, pairs.q_1, pairs.condition))
    )
    base_error = reflow.endpoint_error(reflow.base_flow(PLANAR3R_DIR), validation, steps=1)
    assert state.best_error == pytest.approx(reflow.endpoint_error(student, validation, 1))
    assert state.best_error < 0.5 * base_error
    assert state.step == SMALL.steps and state.best_step > 0


def test_a_stopped_run_resumes_to_the_weights_of_an_uninterrupted_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    config = replace(SMALL, steps=30, checkpoint_minutes=0.0)
    whole, _ = reflow.train_reflow(PLANAR3R_DIR, tmp_path / "whole", config, resume=False)

    calls = 0
    original = reflow.reflow_loss

    def stops_at_step_17(student: torch.nn.Module, *batch: torch.Tensor) -> torch.Tensor:
        nonlocal calls
        calls += 1
        if calls == 17:
            raise KeyboardInterrupt
        return original(student, *batch)

    monkeypatch.setattr(reflow, "reflow_loss", stops_at_step_17)
    with pytest.raises(KeyboardInterrupt):
        reflow.train_reflow(PLANAR3R_DIR, tmp_path / "stopped", config, resume=False)
    monkeypatch.setattr(reflow, "reflow_loss", original)
    resumed, state = reflow.train_reflow(PLANAR3R_DIR, tmp_path / "stopped", config, resume=True)
    assert state.step == config.steps
    assert weights_equal(resumed, whole)
    with pytest.raises(ValueError, match="steps"):
        reflow.train_reflow(
            PLANAR3R_DIR, tmp_path / "stopped", replace(config, steps=31), resume=True
        )


def test_the_export_is_served_and_its_one_step_answers_are_exact(tmp_path: Path) -> None:
    model_dir = _planar_copy(tmp_path)
    student, state = reflow.train_reflow(model_dir, tmp_path / "run", SMALL, resume=False)
    base = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    record = reflow.reflow_record(base, SMALL, state, "smm-train reflow --model-dir x")
    manifest = reflow.export_reflow(
        model_dir, student, record, threads=1, sweep_targets=0, sweep_seed=1, eval_targets=3,
        eval_samples_per_target=100, eval_seed=5,
    )  # fmt: skip
    assert {REFLOW_FILE, REFLOW_INT8_FILE} <= set(manifest.files)
    assert manifest.reflow is not None and manifest.reflow.best_step == state.best_step
    assert manifest.reflow.teacher_sha256 == manifest.files[FLOW_FILE]
    served = load_model(model_dir, threads=1)
    assert served.manifest == manifest
    one_step = SamplerSpec(flow="reflow", steps=1, precision="int8")
    candidate = with_defaults(served, sampler=one_step, num_samples=300)
    target = [1.2, -0.7]
    answer = run(candidate, Query.for_model(candidate.manifest, position_m=target, seed=4))
    assert answer.counts.accepted > 0
    q = np.concatenate([c.configurations_rad.reshape(-1, 3) for c in answer.components])
    assert np.all(np.linalg.norm(planar3r_position(q) - target, axis=1) <= 1e-6)


def test_a_manifest_asking_for_a_missing_reflow_is_refused_by_name(tmp_path: Path) -> None:
    model_dir = _planar_copy(tmp_path)
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    sampler = manifest.defaults.sampler.model_copy(update={"flow": "reflow", "steps": 1})
    manifest = manifest.model_copy(
        update={"defaults": manifest.defaults.model_copy(update={"sampler": sampler})}
    )
    (model_dir / MANIFEST_FILE).write_text(manifest.model_dump_json(indent=2))
    name = REFLOW_INT8_FILE if sampler.precision == "int8" else REFLOW_FILE
    with pytest.raises(ModelVerificationError, match=name):
        load_model(model_dir, threads=1)


def test_the_paper_samplers_row_is_kept_only_for_the_same_targets_and_samples() -> None:
    manifest = Manifest.model_validate_json((PLANAR3R_DIR / MANIFEST_FILE).read_bytes())
    assert manifest.quality is not None
    targets, samples = manifest.quality.held_out_targets, manifest.quality.samples_per_target
    row = reflow.paper_row(manifest, targets, samples)
    assert row is not None and row in manifest.quality.raw
    assert (row.sampler_flow, row.sampler_steps, row.sampler_precision) == ("base", 100, "float32")
    assert reflow.paper_row(manifest, targets + 1, samples) is None
    assert reflow.paper_row(manifest, targets, samples // 2) is None


def test_export_only_keeps_the_training_commit_and_records_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(ValueError, match="train one first"):
        reflow.reflow_model(
            _planar_copy(tmp_path), tmp_path / "runs", SMALL, False, "x", export_only=True
        )
    bundled = Manifest.model_validate_json((PLANAR3R_DIR / MANIFEST_FILE).read_bytes())
    assert bundled.reflow is not None
    exported: dict[str, object] = {}

    def export(model_dir: Path, student: object, record: object, **settings: object) -> None:
        exported.update(student=student, record=record)  # the sweep and judge: test_judge.py

    monkeypatch.setattr(reflow, "export_reflow", export)
    reflow.reflow_model(PLANAR3R_DIR, tmp_path / "runs", SMALL, False, "x", export_only=True)
    record = exported["record"]
    assert exported["student"] is None  # the committed reflow.onnx is kept
    assert isinstance(record, reflow.ReflowRecord)
    assert record.git_commit == bundled.reflow.git_commit
    assert record.export_git_commit == reflow.git_commit()
