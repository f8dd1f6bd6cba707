"""quantise: the int8 flow is a real quantisation of the float32 one, guarded, and served.

The int8 network's weights are int8 (the file shrinks by about 4x) and its velocity
stays within the guard of the float32 network's, but is not equal to it (it is not a
copy); a network whose weights were scaled on the way is refused and nothing is written.
`add_int8` lists flow_int8.onnx in an exported model's manifest without changing its
defaults, and the registry serves it when the sampler's precision asks for int8.
"""

import shutil
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

from service.errors import ModelVerificationError
from service.manifest import (
    FLOW_FILE,
    FLOW_INT8_FILE,
    MANIFEST_FILE,
    REFLOW_FILE,
    REFLOW_INT8_FILE,
    Manifest,
)
from service.models.registry import load_model
from tests.support.app import PLANAR3R_DIR
from training.evaluate.served import with_defaults
from training.quantise import (
    INT8_RELATIVE_ERROR_MAX,
    QuantisationError,
    add_int8,
    int8_relative_error,
    quantise_flow,
)


def _model_without_int8(tmp_path: Path) -> Path:
    """A copy of the bundled planar model (and its robots/) with its float32 flow alone."""
    models = tmp_path / "models"
    shutil.copytree(PLANAR3R_DIR.parent / "robots", models / "robots")
    model_dir = models / PLANAR3R_DIR.name
    shutil.copytree(PLANAR3R_DIR, model_dir)
    dropped = (FLOW_INT8_FILE, REFLOW_FILE, REFLOW_INT8_FILE)  # the float32 flow alone
    for name in dropped:
        (model_dir / name).unlink(missing_ok=True)
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    files = {k: v for k, v in manifest.files.items() if k not in dropped}
    defaults = manifest.defaults.model_copy(
        update={"sampler": manifest.defaults.sampler.model_copy(update={"precision": "float32"})}
    )
    manifest = manifest.model_copy(update={"files": files, "defaults": defaults})
    (model_dir / MANIFEST_FILE).write_text(manifest.model_dump_json(indent=2))
    return model_dir


def test_int8_is_quantised_close_to_float32_but_not_a_copy(tmp_path: Path) -> None:
    int8 = tmp_path / FLOW_INT8_FILE
    error = quantise_flow(PLANAR3R_DIR / FLOW_FILE, int8)
    assert error == int8_relative_error(PLANAR3R_DIR / FLOW_FILE, int8)
    assert 1e-4 < error <= INT8_RELATIVE_ERROR_MAX
    assert int8.stat().st_size < 0.5 * (PLANAR3R_DIR / FLOW_FILE).stat().st_size
    weights = onnx.load(str(int8)).graph.initializer
    assert any(w.data_type == onnx.TensorProto.INT8 for w in weights)


def test_a_broken_quantisation_is_refused_and_nothing_is_written(tmp_path: Path) -> None:
    def quantiser_with_a_wrong_scale(source: str, destination: str, **_: object) -> None:
        # What a quantiser with a wrong weight scale writes: the network, its largest
        # weight matrix three times too large.
        graph = onnx.load(source)
        largest = max(graph.graph.initializer, key=lambda w: int(np.prod(w.dims)))
        scaled = (numpy_helper.to_array(largest) * 3.0).astype(np.float32)
        largest.CopyFrom(numpy_helper.from_array(scaled, largest.name))
        onnx.save(graph, destination)

    int8 = tmp_path / FLOW_INT8_FILE
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("training.quantise.quantize_dynamic", quantiser_with_a_wrong_scale)
        with pytest.raises(QuantisationError, match="beyond"):
            quantise_flow(PLANAR3R_DIR / FLOW_FILE, int8)
    assert not int8.exists()


def test_add_int8_lists_the_network_and_the_registry_serves_it(tmp_path: Path) -> None:
    model_dir = _model_without_int8(tmp_path)
    before = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    model = load_model(model_dir, threads=1)
    assert set(model.networks) == {FLOW_FILE}
    with pytest.raises(ModelVerificationError, match="choose from"):
        _ = with_defaults(
            model,
            sampler=model.manifest.defaults.sampler.model_copy(update={"precision": "int8"}),
        ).velocity

    after = add_int8(model_dir)
    assert FLOW_INT8_FILE in after.files
    assert after.defaults == before.defaults  # serving is not switched by adding it
    model = load_model(model_dir, threads=1)
    assert set(model.networks) == {FLOW_FILE, FLOW_INT8_FILE}
    int8 = with_defaults(
        model, sampler=model.manifest.defaults.sampler.model_copy(update={"precision": "int8"})
    )
    assert int8.velocity is model.networks[FLOW_INT8_FILE]
    assert model.velocity is model.networks[FLOW_FILE]
    rng = np.random.default_rng(0)
    q_t = rng.standard_normal((64, 3), dtype=np.float32)
    t = rng.uniform(0, 1, (64, 1)).astype(np.float32)
    condition = rng.uniform(-1, 1, (64, 2)).astype(np.float32)
    v32, v8 = model.velocity(q_t, t, condition), int8.velocity(q_t, t, condition)
    assert 0 < np.linalg.norm(v8 - v32) <= INT8_RELATIVE_ERROR_MAX * np.linalg.norm(v32)


def test_a_manifest_asking_for_int8_without_the_file_is_refused(tmp_path: Path) -> None:
    model_dir = _model_without_int8(tmp_path)
    manifest = Manifest.model_validate_json((model_dir / MANIFEST_FILE).read_bytes())
    defaults = manifest.defaults.model_copy(
        update={"sampler": manifest.defaults.sampler.model_copy(update={"precision": "int8"})}
    )
    (model_dir / MANIFEST_FILE).write_text(
        manifest.model_copy(update={"defaults": defaults}).model_dump_json(indent=2)
    )
    with pytest.raises(ModelVerificationError, match=FLOW_INT8_FILE):
        load_model(model_dir, threads=1)
