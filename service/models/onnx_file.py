"""An ONNX file's graph read from its protobuf wire format, and a model cut from it.

The compiled int8 flow network (int8_mlp.py) needs the nodes and the initializers of the
exported network, and a model of the nodes before its first quantised layer to run in
onnxruntime. The `onnx` package reads and writes both, but it is ~31 MB installed with
ml_dtypes beside it, and the service needs five message types of its schema: ModelProto,
GraphProto, NodeProto, TensorProto and ValueInfoProto. Their fields are read here by number
(onnx/onnx.proto3; the wire format is protobuf's: a varint key of field number and wire
type, then a varint, 8 bytes, a length-prefixed payload or 4 bytes), every field this
module does not use skipped, and a cut model is written from the file's own bytes of the
nodes, initializers and inputs it keeps. tests/service/models/test_onnx_file.py checks the
reading against the `onnx` package and the cut model against the whole one.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

# Wire types (protobuf encoding).
VARINT, FIXED64, LENGTH, FIXED32 = 0, 1, 2, 5

# ModelProto, GraphProto, NodeProto, TensorProto, ValueInfoProto field numbers (onnx.proto3).
MODEL_IR_VERSION, MODEL_OPSET_IMPORT, MODEL_GRAPH = 1, 8, 7
GRAPH_NODE, GRAPH_NAME, GRAPH_INITIALIZER, GRAPH_INPUT, GRAPH_OUTPUT = 1, 2, 5, 11, 12
NODE_INPUT, NODE_OUTPUT, NODE_OP_TYPE, NODE_ATTRIBUTE, NODE_DOMAIN = 1, 2, 4, 5, 7
ATTRIBUTE_NAME, ATTRIBUTE_INT = 1, 3
TENSOR_DIMS, TENSOR_DATA_TYPE, TENSOR_FLOAT_DATA, TENSOR_INT32_DATA = 1, 2, 4, 5
TENSOR_INT64_DATA, TENSOR_NAME, TENSOR_RAW_DATA = 7, 8, 9
VALUE_NAME, VALUE_TYPE = 1, 2
TYPE_TENSOR, TENSOR_TYPE_ELEM, TENSOR_TYPE_SHAPE, SHAPE_DIM = 1, 1, 2, 1
DIM_VALUE, DIM_PARAM = 1, 2

# TensorProto.DataType -> numpy: the fixed-width numeric types (no strings, no 4-bit).
DTYPES: dict[int, np.dtype] = {
    1: np.dtype("<f4"),  # FLOAT
    2: np.dtype("u1"),  # UINT8
    3: np.dtype("i1"),  # INT8
    4: np.dtype("<u2"),  # UINT16
    5: np.dtype("<i2"),  # INT16
    6: np.dtype("<i4"),  # INT32
    7: np.dtype("<i8"),  # INT64
    9: np.dtype("?"),  # BOOL
    10: np.dtype("<f2"),  # FLOAT16
    11: np.dtype("<f8"),  # DOUBLE
    12: np.dtype("<u4"),  # UINT32
    13: np.dtype("<u8"),  # UINT64
}
FLOAT = 1


class OnnxFormatError(ValueError):
    """The bytes are not an ONNX model this reader understands."""


def _varint(data: bytes, at: int) -> tuple[int, int]:
    """The varint at `at` and the offset after it."""
    value, shift = 0, 0
    while True:
        if at >= len(data):
            raise OnnxFormatError("a varint runs past the end of its message")
        byte = data[at]
        value |= (byte & 0x7F) << shift
        at += 1
        if byte < 0x80:
            return value, at
        shift += 7


def fields(data: bytes) -> Iterator[tuple[int, int, int | bytes]]:
    """(field number, wire type, value) of a message: an int for a varint, bytes else."""
    at = 0
    while at < len(data):
        key, at = _varint(data, at)
        number, wire = key >> 3, key & 7
        if wire == VARINT:
            value, at = _varint(data, at)
            yield number, wire, value
        elif wire in (FIXED64, FIXED32):
            size = 8 if wire == FIXED64 else 4
            yield number, wire, data[at : at + size]
            at += size
        elif wire == LENGTH:
            size, at = _varint(data, at)
            if at + size > len(data):
                raise OnnxFormatError("a field runs past the end of its message")
            yield number, wire, data[at : at + size]
            at += size
        else:
            raise OnnxFormatError(f"wire type {wire} (groups) in an ONNX message")


def _text(value: int | bytes) -> str:
    if not isinstance(value, bytes):
        raise OnnxFormatError("a string field holds a varint")
    return value.decode()


def _signed(value: int) -> int:
    """A varint's int64 (negative values are ten bytes of two's complement)."""
    return value - (1 << 64) if value >= 1 << 63 else value


def _packed_varints(value: int | bytes) -> list[int]:
    if isinstance(value, int):
        return [_signed(value)]
    out, at = [], 0
    while at < len(value):
        item, at = _varint(value, at)
        out.append(_signed(item))
    return out


@dataclass(frozen=True)
class Node:
    op_type: str
    domain: str
    inputs: tuple[str, ...]  # "" for an omitted optional input
    outputs: tuple[str, ...]
    ints: dict[str, int]  # the node's integer attributes (Concat's axis)
    encoded: bytes  # the NodeProto as the file holds it


@dataclass(frozen=True)
class Graph:
    """A model's graph: nodes in the file's (topological) order, initializers by name."""

    nodes: tuple[Node, ...]
    initializers: dict[str, np.ndarray]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    encoded_initializers: dict[str, bytes]
    encoded_inputs: dict[str, bytes]
    ir_version: int
    encoded_opsets: tuple[bytes, ...]

    def producer(self, name: str) -> Node | None:
        """The node whose outputs include `name` (None for an input or initializer)."""
        return next((node for node in self.nodes if name in node.outputs), None)

    def consumers(self, name: str) -> list[Node]:
        """The nodes that take `name` as an input, in the graph's order."""
        return [node for node in self.nodes if name in node.inputs]


def _int_attribute(encoded: bytes) -> tuple[str, int] | None:
    name, value = "", None
    for number, wire, item in fields(encoded):
        if number == ATTRIBUTE_NAME:
            name = _text(item)
        elif number == ATTRIBUTE_INT and wire == VARINT and isinstance(item, int):
            value = _signed(item)
    return None if value is None else (name, value)


def _node(encoded: bytes) -> Node:
    op_type, domain, inputs, outputs = "", "", [], []
    ints: dict[str, int] = {}
    for number, _, value in fields(encoded):
        if number == NODE_ATTRIBUTE and isinstance(value, bytes):
            attribute = _int_attribute(value)
            if attribute is not None:
                ints[attribute[0]] = attribute[1]
        elif number == NODE_INPUT:
            inputs.append(_text(value))
        elif number == NODE_OUTPUT:
            outputs.append(_text(value))
        elif number == NODE_OP_TYPE:
            op_type = _text(value)
        elif number == NODE_DOMAIN:
            domain = _text(value)
    return Node(op_type, domain, tuple(inputs), tuple(outputs), ints, encoded)


def _tensor(encoded: bytes) -> tuple[str, np.ndarray]:
    name, dims, data_type, raw = "", [], 0, None
    floats: list[bytes] = []
    integers: list[int] = []
    for number, _, value in fields(encoded):
        if number == TENSOR_DIMS:
            dims.extend(_packed_varints(value))
        elif number == TENSOR_DATA_TYPE and isinstance(value, int):
            data_type = value
        elif number == TENSOR_NAME:
            name = _text(value)
        elif number == TENSOR_RAW_DATA and isinstance(value, bytes):
            raw = value
        elif number == TENSOR_FLOAT_DATA and isinstance(value, bytes):
            floats.append(value)  # packed, or one fixed32
        elif number in (TENSOR_INT32_DATA, TENSOR_INT64_DATA):
            integers.extend(_packed_varints(value))
    if data_type not in DTYPES:
        raise OnnxFormatError(
            f"initializer {name!r}: data type {data_type}; read: {sorted(DTYPES)}"
        )
    dtype = DTYPES[data_type]
    if raw is not None:
        array = np.frombuffer(raw, dtype=dtype)
    elif floats:
        array = np.frombuffer(b"".join(floats), dtype="<f4").astype(dtype)
    else:
        array = np.array(integers, dtype=np.int64).astype(dtype)
    count = int(np.prod(dims, dtype=np.int64))
    if array.size != count:
        raise OnnxFormatError(f"initializer {name!r}: {array.size} values for dims {dims}")
    return name, array.reshape(dims).copy()


def read_graph(path: Path) -> Graph:
    """The graph of the ONNX model at `path`."""
    model = path.read_bytes()
    graph, ir_version, opsets = None, 0, []
    for number, _, value in fields(model):
        if number == MODEL_GRAPH and isinstance(value, bytes):
            graph = value
        elif number == MODEL_IR_VERSION and isinstance(value, int):
            ir_version = value
        elif number == MODEL_OPSET_IMPORT and isinstance(value, bytes):
            opsets.append(value)
    if graph is None:
        raise OnnxFormatError(f"{path}: no graph")
    nodes: list[Node] = []
    initializers: dict[str, np.ndarray] = {}
    encoded_initializers: dict[str, bytes] = {}
    inputs: list[str] = []
    outputs: list[str] = []
    encoded_inputs: dict[str, bytes] = {}
    for number, _, value in fields(graph):
        if not isinstance(value, bytes):
            continue
        if number == GRAPH_NODE:
            nodes.append(_node(value))
        elif number == GRAPH_INITIALIZER:
            name, array = _tensor(value)
            initializers[name] = array
            encoded_initializers[name] = value
        elif number in (GRAPH_INPUT, GRAPH_OUTPUT):
            name = next((_text(v) for n, _, v in fields(value) if n == VALUE_NAME), "")
            (inputs if number == GRAPH_INPUT else outputs).append(name)
            if number == GRAPH_INPUT:
                encoded_inputs[name] = value
    return Graph(
        nodes=tuple(nodes),
        initializers=initializers,
        inputs=tuple(inputs),
        outputs=tuple(outputs),
        encoded_initializers=encoded_initializers,
        encoded_inputs=encoded_inputs,
        ir_version=ir_version,
        encoded_opsets=tuple(opsets),
    )


def _key(number: int, wire: int) -> bytes:
    return _encode_varint(number << 3 | wire)


def _encode_varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _length_field(number: int, payload: bytes) -> bytes:
    return _key(number, LENGTH) + _encode_varint(len(payload)) + payload


def _float_output(name: str, dims: tuple[int | str, ...]) -> bytes:
    """A ValueInfoProto of a float tensor: a str dim is symbolic, an int fixed."""
    shape = b"".join(
        _length_field(
            SHAPE_DIM,
            _length_field(DIM_PARAM, d.encode())
            if isinstance(d, str)
            else _key(DIM_VALUE, VARINT) + _encode_varint(d),
        )
        for d in dims
    )
    tensor = _key(TENSOR_TYPE_ELEM, VARINT) + _encode_varint(FLOAT)
    tensor += _length_field(TENSOR_TYPE_SHAPE, shape)
    value_type = _length_field(TYPE_TENSOR, tensor)
    return _length_field(VALUE_NAME, name.encode()) + _length_field(VALUE_TYPE, value_type)


def _ancestry(graph: Graph, output: str) -> tuple[list[Node], set[str]]:
    """The nodes `output` depends on, in order, and every name they read."""
    needed, kept = {output}, []
    for node in reversed(graph.nodes):
        if needed & set(node.outputs):
            kept.append(node)
            needed |= {name for name in node.inputs if name}
    kept.reverse()
    return kept, needed


def inputs_needed(graph: Graph, output: str) -> set[str]:
    """The graph inputs `output` depends on (itself, when it is one)."""
    return _ancestry(graph, output)[1] & set(graph.inputs)


def cut_model(graph: Graph, output: str, dims: tuple[int | str, ...]) -> bytes:
    """A model of the nodes `output` depends on, with the inputs and initializers they read
    (the file's own bytes of each) and `output` (float, `dims`) as its one output."""
    kept, needed = _ancestry(graph, output)
    if not kept:
        raise OnnxFormatError(f"no node computes {output!r}")
    body = b"".join(_length_field(GRAPH_NODE, node.encoded) for node in kept)
    body += _length_field(GRAPH_NAME, b"cut")
    body += b"".join(
        _length_field(GRAPH_INITIALIZER, encoded)
        for name, encoded in graph.encoded_initializers.items()
        if name in needed
    )
    body += b"".join(
        _length_field(GRAPH_INPUT, graph.encoded_inputs[name])
        for name in graph.inputs
        if name in needed
    )
    body += _length_field(GRAPH_OUTPUT, _float_output(output, dims))
    model = _key(MODEL_IR_VERSION, VARINT) + _encode_varint(graph.ir_version)
    model += b"".join(_length_field(MODEL_OPSET_IMPORT, opset) for opset in graph.encoded_opsets)
    return model + _length_field(MODEL_GRAPH, body)
