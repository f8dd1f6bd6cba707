"""service/models/onnx_file.py reads every bundled ONNX file as the `onnx` package does
(nodes, initializers, inputs, outputs), and the model it cuts before a node computes that
node's output as a model the `onnx` package extracts from the same file does, to the bit.
"""

from pathlib import Path

import numpy as np
import onnx
import onnx.utils
import pytest
from onnx import numpy_helper

from service.manifest import FLOW_INT8_FILE, REPO_MODELS_DIR
from service.models.onnx_file import OnnxFormatError, cut_model, fields, read_graph
from service.models.sessions import FLOW_INPUTS, open_session

ONNX_FILES = sorted(REPO_MODELS_DIR.glob("*/*.onnx"))


@pytest.mark.parametrize("path", ONNX_FILES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_the_graph_read_is_the_onnx_packages(path: Path) -> None:
    graph, model = read_graph(path), onnx.load(path)
    assert [(n.op_type, n.domain, n.inputs, n.outputs) for n in graph.nodes] == [
        (n.op_type, n.domain, tuple(n.input), tuple(n.output)) for n in model.graph.node
    ]
    assert graph.inputs == tuple(i.name for i in model.graph.input)
    assert graph.outputs == tuple(o.name for o in model.graph.output)
    assert graph.ir_version == model.ir_version
    expected = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    assert graph.initializers.keys() == expected.keys()
    for name, array in expected.items():
        assert graph.initializers[name].dtype == array.dtype, name
        np.testing.assert_array_equal(graph.initializers[name], array)


def test_the_cut_model_computes_what_the_onnx_packages_extract_does(tmp_path: Path) -> None:
    path = REPO_MODELS_DIR / "iiwa14-pose" / FLOW_INT8_FILE
    graph = read_graph(path)
    quantise = next(n for n in graph.nodes if n.op_type == "DynamicQuantizeLinear")
    output = quantise.inputs[0]
    cut = cut_model(graph, output, ("batch", 80))
    extracted = tmp_path / "extracted.onnx"
    onnx.utils.extract_model(str(path), str(extracted), list(FLOW_INPUTS), [output])
    rng = np.random.default_rng(3)
    feeds = {
        "q_t": rng.standard_normal((50, 7)).astype(np.float32),
        "t": rng.uniform(0, 1, (50, 1)).astype(np.float32),
        "condition": rng.standard_normal((50, 9)).astype(np.float32),
    }
    (ours,) = open_session(cut, 1).run([output], feeds)
    (theirs,) = open_session(extracted, 1).run([output], feeds)
    np.testing.assert_array_equal(ours, theirs)
    np.testing.assert_array_equal(ours[:, :7], feeds["q_t"])  # q_t, embedding, condition
    np.testing.assert_array_equal(ours[:, -9:], feeds["condition"])
    # Only the nodes, initializers and inputs the output needs.
    kept = onnx.load_from_string(cut)
    assert {n.op_type for n in kept.graph.node} == {"Mul", "Sin", "Cos", "Concat"}
    assert [i.name for i in kept.graph.initializer] == ["time_embedding.frequencies"]


def test_a_cut_for_an_output_no_node_computes_is_refused() -> None:
    graph = read_graph(REPO_MODELS_DIR / "iiwa14-pose" / FLOW_INT8_FILE)
    with pytest.raises(OnnxFormatError, match="no node computes 'q_t'"):
        cut_model(graph, "q_t", ("batch", 7))


def test_truncated_bytes_are_refused() -> None:
    data = (REPO_MODELS_DIR / "iiwa14-pose" / FLOW_INT8_FILE).read_bytes()
    with pytest.raises(OnnxFormatError, match="past the end"):
        list(fields(data[:1000]))
