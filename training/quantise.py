"""The flow network in int8: onnxruntime dynamic quantisation of the exported flow.onnx.

Every MatMul's weights are stored as int8, one scale per output channel; its input is
quantised per call from the batch's own range (dynamic: no calibration data), and the
products accumulate in int32. The service evaluates it with the exact integer product
(service/models/int8_mlp.py; onnxruntime's saturates on AVX2 without VNNI), and so does the
guard below. Measured on the iiwa14 pose
flow (512 x 5 MLP, 1000 samples, one onnxruntime thread, AMD EPYC with AVX512-VNNI):
21.2 ms per evaluation in float32, 6.8 ms in int8; velocity differing from float32 by
7.4 % (relative L2 norm on random inputs), where per-tensor scales gave 8.3 % and
unsigned weights ran at 15 ms.

Whether int8 serves is not decided here: the sweep measures the sampler with it
(training/sweep/, its raw error against float32's) and the evaluation judges the
answers. Here only a guard: an int8 network whose velocity differs from the float32 one
by more than INT8_RELATIVE_ERROR_MAX on the export's parity inputs is a broken
quantisation, and nothing is written.

    smm-train quantise --model-dir models/iiwa14-pose   # add flow_int8.onnx
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnxruntime.quantization import QuantType, quantize_dynamic

from service.manifest import FLOW_FILE, FLOW_INT8_FILE, MANIFEST_FILE, Manifest
from service.models.registry import load_model, open_flow, sha256_of
from service.models.sessions import FLOW_INPUTS, FLOW_OUTPUT
from training.staging import staged_copy

# Relative L2 difference of int8 from float32 velocities beyond which the quantisation is
# broken (a wrong scale or layout gives ~1); the bundled models measure 0.06-0.08.
INT8_RELATIVE_ERROR_MAX = 0.25
PARITY_BATCH = 1000


class QuantisationError(RuntimeError):
    """The int8 network's velocity is too far from the float32 network's."""


def quantise_flow(float32_path: Path, int8_path: Path) -> float:
    """Write the int8 quantisation of `float32_path` to `int8_path`; its relative error.

    The exporter's value_info (optional shape annotations of intermediate values) holds
    shapes that onnx's shape inference rejects (a (80,) against a (512,) on the first
    layer of the 512-wide MLP), and the quantiser runs shape inference, so the
    annotations are dropped first; the graph itself is untouched.
    """
    graph = onnx.load(str(float32_path))
    del graph.graph.value_info[:]
    with tempfile.TemporaryDirectory() as scratch:
        stripped = Path(scratch) / FLOW_FILE
        onnx.save(graph, str(stripped))
        quantize_dynamic(
            str(stripped), str(int8_path), weight_type=QuantType.QInt8, per_channel=True
        )
    error = int8_relative_error(float32_path, int8_path)
    if not error <= INT8_RELATIVE_ERROR_MAX:
        int8_path.unlink(missing_ok=True)
        raise QuantisationError(
            f"{int8_path}: int8 velocity differs from float32 by {error:.3g} (relative), "
            f"beyond {INT8_RELATIVE_ERROR_MAX}"
        )
    return error


def int8_relative_error(float32_path: Path, int8_path: Path) -> float:
    """|v_int8 - v_float32| / |v_float32| (L2 over a batch) on random inputs: q_t ~ N(0, I),
    t ~ U(0, 1), condition ~ U(-1, 1) (the normalised condition's range), fixed seed; the
    int8 network evaluated as the service evaluates it on this processor (`open_flow`)."""
    float32 = ort.InferenceSession(str(float32_path), providers=["CPUExecutionProvider"])
    int8 = open_flow(int8_path, threads=1, serial=False, compiled_int8=True)
    joint_dim, condition_dim = (float32.get_inputs()[i].shape[1] for i in (0, 2))
    rng = np.random.default_rng(0)
    feeds = dict(
        zip(
            FLOW_INPUTS,
            (
                rng.standard_normal((PARITY_BATCH, joint_dim), dtype=np.float32),
                rng.uniform(0, 1, (PARITY_BATCH, 1)).astype(np.float32),
                rng.uniform(-1, 1, (PARITY_BATCH, condition_dim)).astype(np.float32),
            ),
            strict=True,
        )
    )
    (expected,) = float32.run([FLOW_OUTPUT], feeds)
    actual = int8(**feeds)
    return float(np.linalg.norm(actual - expected) / np.linalg.norm(expected))


def add_int8(model_dir: Path, threads: int = 1) -> Manifest:
    """Write flow_int8.onnx into an exported model and list it in its manifest; the rest
    of the manifest (its defaults included) is unchanged. Done on a hidden copy, loaded as
    the service loads it, and swapped in only when that succeeds."""
    with staged_copy(model_dir) as staging:
        quantise_flow(staging / FLOW_FILE, staging / FLOW_INT8_FILE)
        manifest = Manifest.model_validate_json((staging / MANIFEST_FILE).read_bytes())
        files = {**manifest.files, FLOW_INT8_FILE: sha256_of(staging / FLOW_INT8_FILE)}
        manifest = manifest.model_copy(update={"files": files})
        (staging / MANIFEST_FILE).write_text(
            manifest.model_dump_json(indent=2, exclude_unset=True) + "\n"
        )
        load_model(staging, threads=threads)
    return manifest


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `smm-train quantise`."""
    parser.add_argument("--model-dir", required=True, type=Path)


def run_command(args: argparse.Namespace, parser: argparse.ArgumentParser) -> None:
    """`smm-train quantise`: write the int8 network and list it in the manifest."""
    del parser
    add_int8(args.model_dir)
    print(f"{args.model_dir / FLOW_INT8_FILE}: written and listed in {MANIFEST_FILE}")
