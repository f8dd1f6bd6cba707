"""The int8 flow network evaluated by compiled layers: the quantised network's exact answer
on every processor, faster than onnxruntime.

flow_int8.onnx is the float network with each linear layer's weights quantised to int8
and its input quantised per call (onnxruntime's dynamic quantisation): onnxruntime fuses
each layer into DynamicQuantizeMatMul and QuickGelu and runs them as about forty operator
calls of separate passes over the rows. Its profile at 500 rows on one thread (iiwa14
pose): ~1.5 ms in DynamicQuantizeMatMul, of which the integer product proper is ~0.6 ms,
and ~0.45 ms in QuickGelu. int8_mlp.c does each layer in one pass after quantising its
input: the product on AMX tiles where the processor has them, else on AVX-512 VNNI
(vpdpbusd, exact: four u8 x s8 products into each int32 lane), else on AVX2, the
dequantisation, bias and SiLU on the product's block while it is in cache, the output's
range found as it is written. It keeps onnxruntime's arithmetic in its order (the
quantisation's rounding, MLAS's logistic polynomial and its fused multiply-adds); what
precedes the first quantised layer (the time embedding's sin and cos, whose bits are
Eigen's) runs in onnxruntime, cut from the same file (onnx_file.cut_model).

The integer product is exact on every kernel, and that is why an int8 network is served
here wherever AVX2 is: onnxruntime's product is exact only on processors with VNNI or AMX.
Where VNNI is, the VNNI kernel multiplies about as fast as onnxruntime's
(`python -m tools.onnx_threads` times both).
On AVX2 alone (AMD EPYC before Zen 4, Intel before Cascade Lake) MLAS multiplies u8 by s8
with vpmaddubsw, whose int16 sums of two products saturate, and the iiwa14 pose network's
velocities then differ from the exact ones on nearly every row of a sampler's call, by up
to hundreds (`python -m tools.int8_exactness` measures it on the machine it runs on): the
same request would get another answer from a replica on another processor. Here every
replica computes the exact network (the same integer sums, the same float32 operations in
the same order), which is onnxruntime's to the bit where onnxruntime's product is exact.
The time embedding, computed by onnxruntime before the first quantised layer, is the same
on every x86 processor too: its sin and cos are Eigen's, compiled into onnxruntime for the
baseline instruction set without fused multiply-adds and with no dispatch by processor
(a test pins every bundled network's embedding to that arithmetic, worked out in numpy).

`python -m tools.onnx_threads` times both (at 500 rows on a 2-core Intel Xeon: 1.05 ms on
one thread and 0.67 on two, against onnxruntime's 1.83 and 1.52).
tests/service/models/test_int8_mlp.py pins every kernel to the others (to the bit, every
bundled int8 network, 1 to 1200 rows, on one thread and two), to onnxruntime's session where
its product is exact, to the exact integer product computed apart, and the layers read to
the `onnx` package's reading of the file.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np
import onnxruntime as ort

from service.models import _int8_mlp  # type: ignore[attr-defined]
from service.models.onnx_file import (
    Graph,
    Node,
    OnnxFormatError,
    cut_model,
    inputs_needed,
    read_graph,
)
from service.models.sessions import FLOW_CALLS, FLOW_INPUTS, FLOW_OUTPUT, open_session
from service.pipeline.arrays import Float32Array
from service.pipeline.rows import ANSWERING

# A call made while no other runs takes two threads when its rows times its widest layer
# reach this: 192 rows of the 512-wide networks, 384 of the 256-wide planar 3R. Below it
# the hand-off to the second thread (the row helper, service/pipeline/row_helper.h) and
# the meetings cost more than the thread saves.
# Measured on a 2-core Intel Xeon (one thread against two, at 500 rows: iiwa14 pose 1.05
# against 0.67 ms, planar 3R 0.35 against 0.28; at 128 rows and 256 rows equal).
PARALLEL_MIN_WORK = 192 * 512


# The product's kernels, best first: AMX tiles (with AVX-512 for the rest), AVX-512 VNNI,
# AVX2 with FMA, plain C. All give the same bits; the plain loops are ~50x slower than
# AVX2, so a processor with none of the others keeps onnxruntime's session
# (SERVED_KERNELS).
KERNELS = ("amx", "vnni", "avx2", "plain")
SERVED_KERNELS = ("amx", "vnni", "avx2")


class UnsupportedNetwork(OnnxFormatError):
    """The graph is not a chain of dynamically quantised linear layers this kernel runs."""


@dataclass(frozen=True)
class QuantisedLayer:
    """y = (x quantised per call) @ weight * weight_scale + bias, then SiLU when `silu`."""

    weight: np.ndarray  # (k, n) int8, zero point 0
    weight_scale: np.ndarray  # (n,) float32
    bias: np.ndarray  # (n,) float32
    silu: bool


def _only(nodes: list[Node], op_type: str, after: str) -> Node:
    if len(nodes) != 1 or nodes[0].op_type != op_type:
        found = [node.op_type for node in nodes]
        raise UnsupportedNetwork(f"after {after}: expected one {op_type}, found {found}")
    return nodes[0]


def _other(node: Node, name: str) -> str:
    (other,) = (x for x in node.inputs if x != name)
    return other


def _initializer(graph: Graph, name: str, dtype: str) -> np.ndarray:
    if name not in graph.initializers:
        raise UnsupportedNetwork(f"{name!r} is not an initializer")
    array = graph.initializers[name]
    if array.dtype != np.dtype(dtype):
        raise UnsupportedNetwork(f"{name!r} is {array.dtype}, expected {dtype}")
    return array


def quantised_layers(graph: Graph) -> tuple[str, list[QuantisedLayer]]:
    """(the first layer's input, the layers): the chain from the graph's first
    DynamicQuantizeLinear to its output, as onnxruntime's quantiser writes each layer:

    DynamicQuantizeLinear(x) -> (x_q, x_scale, x_zero); Mul(x_scale, w_scale);
    MatMulInteger(x_q, W, x_zero, w_zero = 0); Cast; Mul(by the scales); Add(bias);
    then Sigmoid and Mul (SiLU) into the next layer, or the graph's output.
    """
    first = next((node for node in graph.nodes if node.op_type == "DynamicQuantizeLinear"), None)
    if first is None:
        raise UnsupportedNetwork("no DynamicQuantizeLinear: not a dynamically quantised network")
    layers, quantise = [], first
    while True:
        x_q, x_scale, x_zero = quantise.outputs
        product = _only(graph.consumers(x_q), "MatMulInteger", quantise.op_type)
        if product.inputs[0] != x_q or product.inputs[2] != x_zero:
            raise UnsupportedNetwork(
                "MatMulInteger does not take the quantised input and zero point"
            )
        weight = _initializer(graph, product.inputs[1], "int8")
        weight_zero = product.inputs[3] if len(product.inputs) > 3 else ""
        if weight_zero and np.any(_initializer(graph, weight_zero, "int8")):
            raise UnsupportedNetwork("weights with a non-zero zero point")
        cast = _only(graph.consumers(product.outputs[0]), "Cast", "MatMulInteger")
        rescale = _only(graph.consumers(cast.outputs[0]), "Mul", "Cast")
        scales = graph.producer(_other(rescale, cast.outputs[0]))
        if scales is None or scales.op_type != "Mul" or x_scale not in scales.inputs:
            raise UnsupportedNetwork("the product is not rescaled by input scale x weight scale")
        weight_scale = _initializer(graph, _other(scales, x_scale), "float32")
        add = _only(graph.consumers(rescale.outputs[0]), "Add", "the rescaling Mul")
        bias = _initializer(graph, _other(add, rescale.outputs[0]), "float32")
        k, n = weight.shape
        if weight_scale.shape != (n,) or bias.shape != (n,):
            raise UnsupportedNetwork(f"a {k} x {n} layer with scales {weight_scale.shape}")
        y = add.outputs[0]
        if y in graph.outputs:
            layers.append(QuantisedLayer(weight, weight_scale, bias, silu=False))
            return first.inputs[0], layers
        gate = _only([c for c in graph.consumers(y) if c.op_type == "Sigmoid"], "Sigmoid", "Add")
        silu = _only(graph.consumers(gate.outputs[0]), "Mul", "Sigmoid")
        if sorted(silu.inputs) != sorted((y, gate.outputs[0])) or len(graph.consumers(y)) != 2:
            raise UnsupportedNetwork("the activation is not SiLU (y * sigmoid(y))")
        layers.append(QuantisedLayer(weight, weight_scale, bias, silu=True))
        quantise = _only(graph.consumers(silu.outputs[0]), "DynamicQuantizeLinear", "SiLU")


# name -> compiled code of each kernel this processor runs, best first: asked once, since
# the processor does not change under a process.
_KERNEL_CODES: dict[str, int] = dict(_int8_mlp.kernels())


def usable_kernels() -> tuple[str, ...]:
    """The product's kernels this processor runs, best first ("plain" always): "amx" needs
    AMX-INT8 tiles and AVX-512F allowed by the operating system, "vnni" AVX-512F, BW and
    VNNI, "avx2" AVX2 and FMA."""
    return tuple(_KERNEL_CODES)


def best_kernel() -> str:
    """The fastest kernel usable here."""
    return usable_kernels()[0]


def kernel_code(kernel: str | None) -> int:
    """The compiled code of `kernel` (None: the best usable here); ValueError naming the
    usable ones for a kernel unknown or not usable on this processor."""
    name = best_kernel() if kernel is None else kernel
    if name not in _KERNEL_CODES:
        raise ValueError(
            f"kernel {name!r} is not usable on this processor; usable here: "
            f"{', '.join(_KERNEL_CODES)} (of {', '.join(KERNELS)})"
        )
    return _KERNEL_CODES[name]


def keep_scratch(size_bytes: int) -> int:
    """Keep the compiled layers' scratch blocks of at most `size_bytes` between calls (two
    at most, one per flow call running at once), so that a call of up to that size reuses
    its pages rather than mapping and faulting them in again; returns the bound it
    replaces. A call needs about 4.6 kB a row of a 512-wide network (5.1 kB on AVX2)."""
    return int(_int8_mlp.keep_scratch(size_bytes))


def set_helper_spin(seconds: float) -> float:
    """How long the layers' row helper (service/pipeline/row_helper.h; the second share of
    a two-thread call) spins for its next call before it sleeps; returns the value it
    replaces. ValueError below 0 or above 1 s."""
    return float(_int8_mlp.helper_spin(float(seconds)))


def helper_parts() -> int:
    """The second shares of two-thread calls the layers' row helper has done in this
    process."""
    return int(_int8_mlp.helper_parts())


def kept_scratch_bytes() -> int:
    """The bytes the kept scratch blocks hold now."""
    return int(_int8_mlp.kept_scratch())


# vpmaddwd multiplies 16 pairs of int16 (8 lanes of two) and sums each lane's two: the
# AVX2 kernel's product, u8 x s8 widened, 16 integer products an instruction.
PRODUCTS_PER_VPMADDWD = 16


def avx2_product_peak(seconds: float = 0.1, threads: int = 1) -> float:
    """The AVX2 kernel's exact integer product at its peak on this processor: integer
    products a second on `threads` threads at once, each running vpmaddwd and nothing else
    for about `seconds` (`_int8_mlp.avx2_peak`, the GIL released). No layer can multiply
    faster on AVX2, so a network's products over this rate is the least time the AVX2
    kernel can take. Each thread's sum is checked against its closed form (the rounds it
    counts were run). ValueError on a processor without AVX2."""
    if "avx2" not in _KERNEL_CODES:
        raise ValueError(f"no AVX2 on this processor; usable kernels: {', '.join(_KERNEL_CODES)}")
    sums = int(_int8_mlp.peak_sums())
    x = (np.arange(16 * sums, dtype=np.int16) % 7 - 3).tobytes()  # small: no lane overflows
    w = (np.arange(16, dtype=np.int16) % 5 - 2).tobytes()
    xs, ws = np.frombuffer(x, np.int16).reshape(sums, 16), np.frombuffer(w, np.int16)
    per_round = int((xs.astype(np.int64) @ ws.astype(np.int64)).sum())
    trial_rounds = 100_000
    start_s = time.perf_counter()
    _int8_mlp.avx2_peak(x, w, trial_rounds)
    trial_s = max(time.perf_counter() - start_s, 1e-6)
    # A lane gains at most 2 * 3 * 2 = 12 a round: 1e8 rounds stay inside int32.
    rounds = int(min(max(trial_rounds * seconds / trial_s, 1000), 100_000_000))
    checksums: list[int] = [0] * threads

    def probe(i: int) -> None:
        checksums[i] = int(_int8_mlp.avx2_peak(x, w, rounds))

    workers = [threading.Thread(target=probe, args=(i,)) for i in range(threads)]
    start_s = time.perf_counter()
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    elapsed_s = time.perf_counter() - start_s
    if checksums != [rounds * per_round] * threads:
        raise RuntimeError(f"avx2_peak summed {checksums}, not {rounds * per_round} each")
    return threads * rounds * sums * PRODUCTS_PER_VPMADDWD / elapsed_s


class QuantisedNetwork:
    """The layers in compiled code: `forward(x)` of the first layer's input (B, k)."""

    def __init__(self, layers: list[QuantisedLayer]) -> None:
        if not layers:
            raise UnsupportedNetwork("no layers")
        for before, after in pairwise(layers):
            if before.weight.shape[1] != after.weight.shape[0]:
                raise UnsupportedNetwork("consecutive layers' widths differ")
        self.width_in = int(layers[0].weight.shape[0])
        self.width_out = int(layers[-1].weight.shape[1])
        self.widest = max(int(layer.weight.shape[1]) for layer in layers)
        # The integer products a row needs: every layer's k x n, padding aside.
        self.products_per_row = sum(int(np.prod(layer.weight.shape)) for layer in layers)
        self._arrays = tuple(
            (
                int(layer.weight.shape[0]),
                int(layer.weight.shape[1]),
                layer.silu,
                np.ascontiguousarray(layer.weight, dtype=np.int8),
                layer.weight.sum(axis=0, dtype=np.int32),
                np.ascontiguousarray(layer.weight_scale, dtype=np.float32),
                np.ascontiguousarray(layer.bias, dtype=np.float32),
            )
            for layer in layers
        )
        self._network = _int8_mlp.network(self._arrays)

    def forward(
        self, x: Float32Array, kernel: str | None = None, threads: int = 1
    ) -> Float32Array:  # (B, k) -> (B, n)
        """The layers on x's rows, on `kernel` (one of KERNELS usable here; None: the best);
        on two threads when `threads` > 1 and there are more than 32 rows (the same bits)."""
        code = kernel_code(kernel)
        x = np.ascontiguousarray(x, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.width_in:
            raise ValueError(f"x has shape {x.shape}; expected (B, {self.width_in})")
        y = np.empty((len(x), self.width_out), dtype=np.float32)
        if len(x):
            _int8_mlp.forward(self._network, x, len(x), code, threads, y)
        return y


class TimeEmbedding:
    """A part of the first layer's input computed from t alone, on a model cut from the file:
    evaluated once per distinct t of a call (a sampler's call has one), and kept for the
    last KEPT_TIMES values of t (a sampler's time grid has a few dozen at most), since a
    request's steps and rounds ask for the same few."""

    KEPT_TIMES = 64

    def __init__(self, output: str, session: ort.InferenceSession) -> None:
        self.output = output
        self.session = session
        self._kept: dict[bytes, Float32Array] = {}  # t's float32 bits -> its row (1, w)

    def row(self, t: Float32Array) -> Float32Array:  # (1, 1) -> (1, w)
        key = t.tobytes()
        row = self._kept.get(key)
        if row is None:
            (row,) = self.session.run([self.output], {"t": t})
            if len(self._kept) >= self.KEPT_TIMES:
                self._kept.clear()
            self._kept[key] = row
        return row

    def __call__(self, t: Float32Array) -> Float32Array:  # (B, 1) -> (B, w)
        column = t[:, 0]
        if len(column) and column.min() == column.max():  # one t: one row, broadcast
            row = self.row(np.ascontiguousarray(t[:1]))
            return np.broadcast_to(row, (len(t), row.shape[1]))
        values, index = np.unique(column, return_inverse=True)
        (rows,) = self.session.run([self.output], {"t": values[:, None]})
        return rows[index.reshape(-1)]


Part = str | TimeEmbedding  # a flow input by name, or a part computed from t


def _first_input_parts(graph: Graph, first_input: str) -> list[Part] | None:
    """The first layer's input as the concatenation of flow inputs and parts of t alone, or
    None when it is not one (then a model cut from the file computes it whole)."""
    concat = graph.producer(first_input)
    if concat is None or concat.op_type != "Concat" or concat.ints.get("axis") not in (1, -1):
        return None
    parts: list[Part] = []
    for name in concat.inputs:
        if name in FLOW_INPUTS:
            parts.append(name)
        elif inputs_needed(graph, name) == {"t"}:
            model = cut_model(graph, name, ("batch", "width"))
            parts.append(TimeEmbedding(name, open_session(model, 1)))
        else:
            return None
    return parts


class CompiledVelocityField:
    """The int8 flow network: the quantised layers compiled; the first layer's input (the
    time embedding beside q_t and the condition) in onnxruntime, on models cut from the
    file: the embedding of each distinct t of a call once, when the input is a
    concatenation of flow inputs and parts of t alone, else the whole input."""

    def __init__(
        self,
        prefix: ort.InferenceSession | None,
        prefix_output: str,
        parts: list[Part] | None,
        network: QuantisedNetwork,
        kernel: str | None = None,
        threads: int = 1,
        parallel_min_work: int = PARALLEL_MIN_WORK,
    ) -> None:
        self._prefix = prefix
        self._prefix_output = prefix_output
        self._parts = parts
        self._network = network
        self.kernel = best_kernel() if kernel is None else kernel
        kernel_code(self.kernel)  # refused here, naming the usable ones, if not usable
        self._threads = threads
        self._parallel_min_work = parallel_min_work

    @classmethod
    def open(
        cls, path: Path, kernel: str | None = None, threads: int = 1, by_time: bool = True
    ) -> CompiledVelocityField:
        """The network at `path` on `kernel` (None: the best usable here); UnsupportedNetwork
        when it is not a chain of dynamically quantised layers with flow.onnx's inputs and
        output. A call of PARALLEL_MIN_WORK
        (rows times the widest layer) made while no other flow call runs takes two threads
        when `threads` > 1. `by_time`: the embedding once per distinct t where the graph allows
        (False: the whole input on every row)."""
        graph = read_graph(path)
        if graph.inputs != FLOW_INPUTS or graph.outputs != (FLOW_OUTPUT,):
            raise UnsupportedNetwork(f"inputs {graph.inputs}, outputs {graph.outputs}")
        first_input, layers = quantised_layers(graph)
        network = QuantisedNetwork(layers)
        parts = _first_input_parts(graph, first_input) if by_time else None
        prefix = None  # the whole first input cut from the file, only where no parts are
        if parts is None:
            prefix = open_session(cut_model(graph, first_input, ("batch", network.width_in)), 1)
        return cls(prefix, first_input, parts, network, kernel, threads)

    @property
    def layers(self) -> QuantisedNetwork:
        """The quantised layers, from the first layer's input on (the time embedding aside)."""
        return self._network

    def first_input(
        self,
        q_t: Float32Array,  # (B, n)
        t: Float32Array,  # (B, 1)
        condition: Float32Array,  # (B, c)
    ) -> Float32Array:  # (B, k)
        """The first quantised layer's input."""
        feeds = dict(zip(FLOW_INPUTS, (q_t, t, condition), strict=True))
        if self._prefix is not None:
            (x,) = self._prefix.run([self._prefix_output], feeds)
            return np.asarray(x, dtype=np.float32)
        assert self._parts is not None  # one or the other, by `open`
        pieces = [feeds[p] if isinstance(p, str) else p(t) for p in self._parts]
        return np.concatenate(pieces, axis=1, dtype=np.float32)

    def __call__(
        self,
        q_t: Float32Array,  # (B, n)
        t: Float32Array,  # (B, 1)
        condition: Float32Array,  # (B, c)
    ) -> Float32Array:  # (B, n)
        x = self.first_input(q_t, t, condition)  # (B, k)
        with FLOW_CALLS.entered() as others:
            work = len(x) * self._network.widest
            alone_and_large = others == 0 and ANSWERING.alone and work >= self._parallel_min_work
            threads = self._threads if alone_and_large else 1
            return self._network.forward(x, self.kernel, threads)
