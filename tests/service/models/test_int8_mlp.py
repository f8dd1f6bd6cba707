"""The compiled int8 flow layers (service/models/int8_mlp.py) compute the quantised network
exactly: a layer's output is, to the bit, the one worked out here with numpy's int64
product (where a saturating product, onnxruntime's on AVX2 without VNNI, differs); every
kernel this processor has (AMX, AVX-512 VNNI, AVX2, plain C) gives the same bits on every
bundled int8 network from 1 row to more than a block's, on one thread and two, from
concurrent threads;
and onnxruntime's velocities to the bit where its product is exact (VNNI or AMX). The layers
read from the file are the file's (the `onnx` package reads them too); a network of other
layers or a kernel the processor lacks is refused, naming what it found or what is usable;
the registry serves an int8 network on the compiled layers where AMX, VNNI or AVX2 is and
the setting allows.
"""

import threading
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

from service.config import Settings
from service.main import create_app
from service.manifest import FLOW_FILE, FLOW_INT8_FILE, REPO_MODELS_DIR
from service.models import _int8_mlp  # type: ignore[attr-defined]
from service.models.int8_mlp import (
    PARALLEL_MIN_WORK,
    CompiledVelocityField,
    QuantisedLayer,
    QuantisedNetwork,
    TimeEmbedding,
    UnsupportedNetwork,
    avx2_product_peak,
    best_kernel,
    keep_scratch,
    kept_scratch_bytes,
    quantised_layers,
    usable_kernels,
)
from service.models.onnx_file import cut_model, read_graph
from service.models.registry import (
    INT8_FLOW_FILES,
    int8_on_compiled_layers,
    load_model,
    open_flow,
)
from service.models.sessions import FLOW_CALLS, FLOW_INPUTS, OnnxVelocityField, open_session
from tests.support.app import PLANAR3R_DIR
from tests.support.bundled import bundled_model_ids
from tools.int8_exactness import onnxruntime_product_exact

IIWA14_POSE_INT8 = REPO_MODELS_DIR / "iiwa14-pose" / FLOW_INT8_FILE
KERNELS_HERE = usable_kernels()
needs_exact_onnxruntime = pytest.mark.skipif(
    not onnxruntime_product_exact(), reason="onnxruntime's int8 product saturates here"
)


def _int8_flows() -> list[Path]:
    return [
        REPO_MODELS_DIR / model_id / name
        for model_id in bundled_model_ids()
        for name in INT8_FLOW_FILES
        if (REPO_MODELS_DIR / model_id / name).is_file()
    ]


def _inputs(path: Path, rows: int, seed: int) -> dict[str, np.ndarray]:
    """Inputs like a sampler's: q_t ~ N(0, I) with a few far draws, one t, a condition."""
    n, c = (open_session(path, 1).get_inputs()[k].shape[1] for k in (0, 2))
    rng = np.random.default_rng(seed)
    q_t = rng.standard_normal((rows, n)).astype(np.float32)
    q_t[:: max(1, rows // 5)] *= 4.0
    t = np.full((rows, 1), rng.uniform(0, 1), dtype=np.float32)
    condition = rng.uniform(-1, 1, (rows, c)).astype(np.float32)
    return dict(zip(FLOW_INPUTS, (q_t, t, condition), strict=True))


@needs_exact_onnxruntime
@pytest.mark.parametrize("path", _int8_flows(), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_the_compiled_layers_give_onnxruntimes_velocities_to_the_bit(path: Path) -> None:
    """Row counts below, at and past the 32-row blocks' edges, and a sampler's 500 rows
    (1.3 million quantised values per call: a rounding that differs from onnxruntime's on
    one in 10^5 of them, as x * (1 / scale) for x / scale does, shows)."""
    session = open_session(path, 1)
    flows = [CompiledVelocityField.open(path, kernel=kernel) for kernel in KERNELS_HERE]
    for rows in (1, 2, 31, 32, 33, 500):
        inputs = _inputs(path, rows, seed=rows)
        (expected,) = session.run(["velocity"], inputs)
        for flow in flows:
            np.testing.assert_array_equal(flow(**inputs), expected, err_msg=flow.kernel)


@pytest.mark.parametrize("path", _int8_flows(), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_kernel_here_gives_the_same_bits(path: Path) -> None:
    """Row counts around the AVX2 kernel's 4-row blocks, VNNI's 8-row ones and AMX's and
    VNNI's 32-row ones, a sampler's 500 and 1200 rows, on one thread and two: every kernel
    against the plain C loops."""
    flows = {kernel: CompiledVelocityField.open(path, kernel=kernel) for kernel in KERNELS_HERE}
    for rows in (1, 2, 3, 4, 5, 7, 8, 9, 31, 32, 33, 41, 500, 1200):
        inputs = _inputs(path, rows, seed=rows)
        expected = flows["plain"](**inputs)
        for kernel, flow in flows.items():
            for threads in (1, 2):
                velocity = flow._network.forward(flow.first_input(**inputs), kernel, threads)
                np.testing.assert_array_equal(velocity, expected, err_msg=f"{kernel} {threads}")


def _quantised(x: np.ndarray) -> tuple[np.ndarray, np.float32, int]:
    """onnxruntime's DynamicQuantizeLinear in float32: (uint8 values as int64, scale, zp)."""
    low, high = min(np.float32(x.min()), np.float32(0)), max(np.float32(x.max()), np.float32(0))
    scale = np.float32(1) if high == low else np.float32(high - low) / np.float32(255)
    zero_point = int(np.rint(np.clip(np.float32(0) - low / scale, 0, 255)))
    q = np.rint(np.clip(x / scale, np.float32(-zero_point), np.float32(255 - zero_point)))
    return q.astype(np.int64) + zero_point, scale, zero_point


def _layer_by_numpy(x: np.ndarray, layer: QuantisedLayer, saturate: bool) -> np.ndarray:
    """One layer without SiLU: the int64 product (each pair of products clipped to int16
    when `saturate`, as vpmaddubsw does), then (acc - zp colsum) * (scale w_scale) + bias in
    float32, a multiply and an add."""
    a, scale, zero_point = _quantised(x)
    weight = layer.weight.astype(np.int64)
    if saturate:
        k = len(weight) + len(weight) % 2
        a2 = np.zeros((len(a), k), np.int64)
        a2[:, : a.shape[1]] = a
        w2 = np.zeros((k, weight.shape[1]), np.int64)
        w2[: len(weight)] = weight
        pairs = a2[:, 0::2, None] * w2[None, 0::2] + a2[:, 1::2, None] * w2[None, 1::2]
        acc = np.clip(pairs, -32768, 32767).sum(axis=1)
    else:
        acc = a @ weight
    shifted = (acc - zero_point * weight.sum(axis=0)).astype(np.float32)
    return shifted * (scale * layer.weight_scale) + layer.bias


def test_each_layers_product_is_exact_where_a_saturating_one_is_not() -> None:
    """Each layer of the iiwa14 pose network alone (SiLU off), on inputs a layer sees (the
    network's own activations at a sampler's rows): every kernel gives numpy's exact int64
    product to the bit, and on these rows a product saturating at int16 pairs gives other
    values, so a saturating kernel would fail here."""
    _, layers = quantised_layers(read_graph(IIWA14_POSE_INT8))
    inputs = _inputs(IIWA14_POSE_INT8, 500, seed=3)
    x = CompiledVelocityField.open(IIWA14_POSE_INT8).first_input(**inputs)
    saturated_somewhere = False
    for layer in layers:
        alone = QuantisedNetwork([QuantisedLayer(layer.weight, layer.weight_scale,
                                                 layer.bias, silu=False)])  # fmt: skip
        exact = _layer_by_numpy(x, layer, saturate=False)
        for kernel in KERNELS_HERE:
            np.testing.assert_array_equal(alone.forward(x, kernel), exact, err_msg=kernel)
        saturated_somewhere |= not np.array_equal(_layer_by_numpy(x, layer, True), exact)
        x = QuantisedNetwork([layer]).forward(x)  # the next layer's input, SiLU on
    assert saturated_somewhere


def test_the_embedding_once_per_distinct_t_is_the_embedding_of_every_row() -> None:
    """Rows of one t, rows of many (and repeated) t: the first layer's input, built from
    the embedding of each distinct t, is the cut model's on every row, to the bit."""
    by_time = CompiledVelocityField.open(IIWA14_POSE_INT8)
    whole = CompiledVelocityField.open(IIWA14_POSE_INT8, by_time=False)
    assert by_time._parts is not None and whole._parts is None
    rng = np.random.default_rng(11)
    for rows in (1, 7, 500):
        inputs = _inputs(IIWA14_POSE_INT8, rows, seed=rows)
        for t in (inputs["t"], rng.choice([0.0, 0.25, 0.9], (rows, 1)).astype(np.float32)):
            inputs["t"] = t
            np.testing.assert_array_equal(
                by_time.first_input(**inputs), whole.first_input(**inputs)
            )
            np.testing.assert_array_equal(by_time(**inputs), whole(**inputs))
    # The rows kept for the t already seen are the ones the cut model gives.
    for part in by_time._parts:
        if isinstance(part, TimeEmbedding):
            assert part._kept
            for key, row in part._kept.items():
                t = np.frombuffer(key, dtype=np.float32).reshape(1, 1)
                np.testing.assert_array_equal(row, part.session.run([part.output], {"t": t})[0])


def _eigen_sincos(x: np.ndarray, sine: bool) -> np.ndarray:
    """Eigen's psincos_float without fused multiply-adds (Eigen/src/Core/arch/Default/
    GenericPacketMathFunctions.h): rounding to the nearest quarter turn, a four-part
    reduction, the sine or cosine polynomial on [-pi/4, pi/4], the sign from the quadrant.
    Each float32 operation rounds on its own (numpy's), as SSE's separate mul and add do.
    Arguments under 18838, where it reduces without its fallback for huge ones."""
    f32 = np.float32

    def madd(a: np.ndarray, b: np.float32 | np.ndarray, c: np.float32 | np.ndarray) -> np.ndarray:
        return (a * b).astype(f32) + c

    x = np.asarray(x, dtype=f32)
    assert np.abs(x).max() < 18838.0
    y_round = np.abs(x) * f32(0.636619746685028076171875) + f32(12582912)  # 2/pi, 2^23 + 2^22
    quadrant = y_round.view(np.int32)
    y = y_round - f32(12582912)
    r = np.abs(x)
    for part in (-1.5703125, -0.000483989715576171875, 1.62865035235881805419921875e-07,
                 5.5644315544167710640977020375430583953857421875e-11):  # fmt: skip
        r = madd(y, f32(part), r)
    r2 = r * r
    cosine = np.full_like(r, f32(2.4372266125283204019069671630859375e-05))
    for c in (-0.00138865201734006404876708984375, 0.041666619479656219482421875, -0.5, 1.0):
        cosine = madd(cosine, r2, f32(c))
    sine_ = np.full_like(
        r, f32(-0.0001959234114083702898469196984621021329076029360294342041015625)
    )
    for c in (0.0083326873655616851693794799871284340042620897293090820312500000,
              -0.1666666203982298255503735617821803316473960876464843750000000000):  # fmt: skip
        sine_ = madd(sine_, r2, f32(c))
    sine_ = madd(sine_ * r2, r, r)
    even = (quadrant & 1) == 0
    value = np.where(even, sine_, cosine) if sine else np.where(even, cosine, sine_)
    sign = (x.view(np.int32) ^ (quadrant << 30)) if sine else ((quadrant + 1) << 30)
    return (value.view(np.int32) ^ (sign & np.int32(-(2**31)))).view(f32)


@pytest.mark.parametrize("path", _int8_flows(), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_the_time_embedding_is_eigens_sin_and_cos_without_fused_multiply_adds(
    path: Path,
) -> None:
    """What the compiled layers take from onnxruntime, sin and cos of t times the
    frequencies, is Eigen's arithmetic without fused multiply-adds, to the bit, on a
    sampler's every t and 40,000 more: code compiled into onnxruntime for the baseline
    instruction set, with no dispatch by processor, so the same bits on every x86
    processor (this one has FMA and the bits show none). A change of onnxruntime's (or a
    processor that computed otherwise) fails here before it moves an answer."""
    graph = read_graph(path)
    (concat,) = [node for node in graph.nodes if node.op_type == "Concat" and "q_t" in node.inputs]
    embedding = next(name for name in concat.inputs if name not in FLOW_INPUTS)
    sin_and_cos = graph.producer(embedding)
    assert sin_and_cos is not None and sin_and_cos.op_type == "Concat"
    sin, cos = (graph.producer(name) for name in sin_and_cos.inputs)
    assert sin is not None and cos is not None and (sin.op_type, cos.op_type) == ("Sin", "Cos")
    product = graph.producer(sin.inputs[0])
    assert product is not None and product.op_type == "Mul" and product.inputs[0] == "t"
    frequencies = graph.initializers[product.inputs[1]].astype(np.float32)  # (1, F)
    f32 = np.float32
    steps = (np.arange(101) / f32(100)).astype(f32)
    t = np.unique(
        np.concatenate(
            [
                steps,
                steps**2,  # a time power of 2, as the iiwa14 pose's sampler spaces its steps
                np.linspace(0, 1, 20_001, dtype=f32),
                np.random.default_rng(5).uniform(0, 1, 20_000).astype(f32),
            ]
        ).astype(f32)
    )[:, None]  # (T, 1)
    session = open_session(cut_model(graph, embedding, ("batch", "width")), 1)
    (onnxruntime,) = session.run([embedding], {"t": t})
    argument = (t * frequencies).astype(f32)  # Mul: one float32 rounding
    expected = np.concatenate([_eigen_sincos(argument, True), _eigen_sincos(argument, False)], 1)
    np.testing.assert_array_equal(onnxruntime.view(np.int32), expected.view(np.int32))
    # Not libm's: the correctly rounded sine differs in some (so this test can tell).
    libm = np.sin(argument.astype(np.float64)).astype(f32)
    assert (libm != expected[:, : frequencies.shape[1]]).any()


@pytest.mark.parametrize("kernel", KERNELS_HERE)
def test_two_threads_give_one_threads_bits(kernel: str) -> None:
    """The rows split at a 32-row block, each share's range met once a layer: every row
    count, around the split and the blocks' edges, gives the one-thread velocities."""
    _, layers = quantised_layers(read_graph(IIWA14_POSE_INT8))
    network = QuantisedNetwork(layers)
    rng = np.random.default_rng(5)
    for rows in (1, 32, 33, 63, 64, 65, 97, 500) if kernel != "plain" else (33, 65, 97):
        x = rng.standard_normal((rows, network.width_in)).astype(np.float32)
        x[rows // 2] *= 8.0  # the range from one share only
        one = network.forward(x, kernel, threads=1)
        np.testing.assert_array_equal(network.forward(x, kernel, threads=2), one)


def test_a_kernel_this_processor_lacks_is_refused_naming_the_usable_ones() -> None:
    _, layers = quantised_layers(read_graph(IIWA14_POSE_INT8))
    network = QuantisedNetwork(layers)
    x = np.zeros((2, 80), np.float32)
    usable = ", ".join(KERNELS_HERE)
    for kernel in ("sse9", *(k for k in ("amx", "vnni", "avx2") if k not in KERNELS_HERE)):
        with pytest.raises(ValueError, match=f"kernel '{kernel}' is not usable.*{usable}"):
            network.forward(x, kernel)
        with pytest.raises(ValueError, match=f"usable here: {usable}"):
            CompiledVelocityField.open(IIWA14_POSE_INT8, kernel=kernel)
    assert KERNELS_HERE[-1] == "plain" and best_kernel() == KERNELS_HERE[0]


def test_concurrent_calls_of_different_sizes_give_their_single_answers() -> None:
    """Calls share the kernel's kept scratch blocks and its one row helper: none may see
    another's scratch, on one thread or on two (a call that finds the helper taken runs on
    its caller's thread alone)."""
    _, layers = quantised_layers(read_graph(IIWA14_POSE_INT8))
    network = QuantisedNetwork(layers)
    rng = np.random.default_rng(9)
    calls = [
        rng.standard_normal((rows, network.width_in)).astype(np.float32)
        for rows in (3, 40, 500, 1200, 64, 900)
    ]
    expected = [network.forward(x) for x in calls]
    results: dict[int, list[np.ndarray]] = {k: [] for k in range(len(calls))}

    def run(k: int) -> None:
        for repeat in range(6):
            results[k].append(network.forward(calls[k], threads=1 + repeat % 2))

    threads = [threading.Thread(target=run, args=(k,)) for k in range(len(calls))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for k, velocities in results.items():
        for velocity in velocities:
            np.testing.assert_array_equal(velocity, expected[k])


def test_scratch_blocks_are_kept_up_to_the_bound_and_the_answers_do_not_depend_on_it() -> None:
    """A call's scratch block stays for the next call when it is no larger than the bound
    (`keep_scratch`, the service's SMM_FLOW_SCRATCH_BYTES), and is freed otherwise;
    lowering the bound frees the kept blocks above it. The velocities are the same bits
    whether a call reuses a kept block (holding an earlier call's rows) or maps its own."""
    _, layers = quantised_layers(read_graph(IIWA14_POSE_INT8))
    network = QuantisedNetwork(layers)
    rng = np.random.default_rng(13)
    small, large = (
        rng.standard_normal((rows, network.width_in)).astype(np.float32) for rows in (300, 3000)
    )
    before = keep_scratch(0)  # nothing kept: every call maps and frees its own block
    try:
        assert kept_scratch_bytes() == 0
        expected_small, expected_large = network.forward(small), network.forward(large)
        assert kept_scratch_bytes() == 0
        # 3,000 rows of 512 need about 14 MB: kept under a 16 MiB bound, not under 1 MiB.
        keep_scratch(1 << 20)
        network.forward(large)
        assert kept_scratch_bytes() == 0
        keep_scratch(16 << 20)
        np.testing.assert_array_equal(network.forward(large), expected_large)
        held = kept_scratch_bytes()
        assert 3000 * 4 * 512 < held <= 16 << 20
        # The kept block serves the smaller call, its bytes left from the larger one.
        np.testing.assert_array_equal(network.forward(small), expected_small)
        np.testing.assert_array_equal(network.forward(large), expected_large)
        assert kept_scratch_bytes() == held
        keep_scratch(1 << 20)  # lowered below the kept block: freed
        assert kept_scratch_bytes() == 0
    finally:
        keep_scratch(before)


def test_the_service_sets_the_bound_from_its_settings() -> None:
    before = keep_scratch(0)
    try:
        create_app(Settings(flow_scratch_bytes=3 << 20))
        assert keep_scratch(before) == 3 << 20
    finally:
        keep_scratch(before)


def test_the_layers_read_are_the_files_weights_scales_and_biases() -> None:
    """Against the `onnx` package's reading of the same file: each layer's int8 weight,
    its per-column scale and its bias, in order, SiLU after all but the last."""
    first_input, layers = quantised_layers(read_graph(IIWA14_POSE_INT8))
    model = onnx.load(IIWA14_POSE_INT8)
    arrays = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    products = [node for node in model.graph.node if node.op_type == "MatMulInteger"]
    quantise = next(n for n in model.graph.node if n.op_type == "DynamicQuantizeLinear")
    assert first_input == quantise.input[0]
    assert len(layers) == len(products)
    adds = [node for node in model.graph.node if node.op_type == "Add"]
    scales = [
        node
        for node in model.graph.node
        if node.op_type == "Mul" and any(name.endswith("weight_scale") for name in node.input)
    ]
    for layer, product, add, scale in zip(layers, products, adds, scales, strict=True):
        np.testing.assert_array_equal(layer.weight, arrays[product.input[1]])
        np.testing.assert_array_equal(layer.bias, arrays[add.input[1]])
        np.testing.assert_array_equal(layer.weight_scale, arrays[scale.input[1]])
    assert [layer.silu for layer in layers] == [True] * (len(layers) - 1) + [False]


def test_a_rows_products_are_every_matmuls_k_times_n_in_the_file() -> None:
    """The integer products a row needs, against the `onnx` package's reading: the sum over
    the file's MatMulInteger weights of k x n (1,093,120 for the iiwa14 pose network: an
    80-wide input, four 512 x 512 layers, 7 velocities)."""
    model = onnx.load(IIWA14_POSE_INT8)
    arrays = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    products = [n for n in model.graph.node if n.op_type == "MatMulInteger"]
    expected = sum(arrays[node.input[1]].size for node in products)
    _, layers = quantised_layers(read_graph(IIWA14_POSE_INT8))
    assert QuantisedNetwork(layers).products_per_row == expected == 80 * 512 + 4 * 512**2 + 512 * 7


@pytest.mark.skipif("avx2" not in KERNELS_HERE, reason="no AVX2 on this processor")
def test_the_avx2_peak_probe_does_the_products_it_counts() -> None:
    """`avx2_peak`'s sum is rounds times its vectors' dot products with the weights, worked
    out in numpy (so it runs the rounds it is asked for, each with every product summed);
    the rate is positive and finite on one thread and on two at once; bad arguments are
    refused."""
    sums = int(_int8_mlp.peak_sums())
    rng = np.random.default_rng(0)
    x = rng.integers(-3, 4, (sums, 16)).astype(np.int16)
    w = rng.integers(-2, 3, 16).astype(np.int16)
    per_round = int((x.astype(np.int64) @ w.astype(np.int64)).sum())
    for rounds in (0, 1, 7, 12_345):
        assert _int8_mlp.avx2_peak(x.tobytes(), w.tobytes(), rounds) == rounds * per_round
    for threads in (1, 2):
        rate = avx2_product_peak(0.01, threads)
        assert 0 < rate < float("inf")
    with pytest.raises(ValueError, match=f"x of {16 * sums} int16 and w of 16"):
        _int8_mlp.avx2_peak(x.tobytes()[:-2], w.tobytes(), 1)
    with pytest.raises(ValueError, match="rounds must be >= 0"):
        _int8_mlp.avx2_peak(x.tobytes(), w.tobytes(), -1)


def test_a_network_of_other_layers_is_refused_naming_what_it_found() -> None:
    with pytest.raises(UnsupportedNetwork, match="no DynamicQuantizeLinear"):
        CompiledVelocityField.open(PLANAR3R_DIR / FLOW_FILE)


def test_a_call_of_the_wrong_width_is_refused() -> None:
    _, layers = quantised_layers(read_graph(IIWA14_POSE_INT8))
    network = QuantisedNetwork(layers)
    with pytest.raises(ValueError, match=r"expected \(B, 80\)"):
        network.forward(np.zeros((4, 79), np.float32))
    assert network.forward(np.zeros((0, 80), np.float32)).shape == (0, 7)


def test_a_large_call_takes_two_threads_only_when_no_other_runs() -> None:
    """As onnxruntime's sessions (sessions.FLOW_CALLS): a second thread for a call made
    beside another would take a core from it."""
    flow = CompiledVelocityField.open(IIWA14_POSE_INT8, threads=2)
    taken: list[int] = []
    network = flow._network
    real = network.forward

    def spy(x: np.ndarray, kernel: str | None = None, threads: int = 1) -> np.ndarray:
        taken.append(threads)
        return real(x, kernel, threads)

    network.forward = spy  # type: ignore[method-assign]
    least = PARALLEL_MIN_WORK // network.widest  # the fewest rows of this 512-wide network
    large, small = (_inputs(IIWA14_POSE_INT8, rows, seed=1) for rows in (least, least - 1))
    flow(**large)
    flow(**small)
    with FLOW_CALLS.entered():
        flow(**large)
    assert taken == [2, 1, 1]


def test_the_registry_serves_int8_on_the_compiled_layers_where_amx_vnni_or_avx2_is() -> None:
    compiled = open_flow(IIWA14_POSE_INT8, threads=1, serial=False, compiled_int8=True)
    assert int8_on_compiled_layers() == (best_kernel() in ("amx", "vnni", "avx2"))
    expected = CompiledVelocityField if int8_on_compiled_layers() else OnnxVelocityField
    assert isinstance(compiled, expected)
    session = open_flow(IIWA14_POSE_INT8, threads=1, serial=False, compiled_int8=False)
    assert isinstance(session, OnnxVelocityField)
    float_flow = open_flow(PLANAR3R_DIR / FLOW_FILE, threads=1, serial=False, compiled_int8=True)
    assert isinstance(float_flow, OnnxVelocityField)
    model = load_model(REPO_MODELS_DIR / "iiwa14-pose", threads=1)
    assert isinstance(model.networks[FLOW_INT8_FILE], expected)
