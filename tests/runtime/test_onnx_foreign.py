"""ONNX graphs from strangers (:mod:`blenav.onnx_io`).

- A graph may keep its weights in files beside it (ONNX external data); blenav's exports never do. Hashing such a
  graph's weights read every file it names, whatever its size: a 134-byte graph naming a 1 GB data file took 2 GB of
  memory in :func:`blenav.onnx_io.check_weights`, past the graph's own size bound. Refused, nothing read.
- A metadata value nested thousands deep was a RecursionError traceback in :func:`blenav.onnx_io.read_metadata`; it
  stays the string it is, as any value that is not JSON."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from blenav.onnx_io import check_weights, read_metadata, session, weights_props


def _graph(tmp_path, external: bool, metadata: dict | None = None):
    n = 1000
    if external:
        w = TensorProto(name="W", data_type=TensorProto.FLOAT, dims=[n], data_location=TensorProto.EXTERNAL)
        for k, v in (("location", "w.bin"), ("offset", "0"), ("length", str(4 * n))):
            w.external_data.add(key=k, value=v)
        (tmp_path / "w.bin").write_bytes(np.arange(n, dtype="<f4").tobytes())
    else:
        w = numpy_helper.from_array(np.arange(n, dtype=np.float32), "W")
    g = helper.make_graph([helper.make_node("Add", ["x", "W"], ["y"])], "g",
                          [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                          [helper.make_tensor_value_info("y", TensorProto.FLOAT, [n])], [w])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    if not external:
        for k, v in {**(metadata or {}), **weights_props(m)}.items():
            m.metadata_props.add(key=k, value=v)
    onnx.save(m, tmp_path / "m.onnx")
    return tmp_path / "m.onnx"


def test_weights_in_external_files_are_refused_before_they_are_read(tmp_path):
    path = _graph(tmp_path, external=True)
    with pytest.raises(ValueError) as e:
        check_weights(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: weights W are stored in external data files") and "\n" not in msg


def test_weights_in_the_graph_still_hash(tmp_path):
    path = _graph(tmp_path, external=False)
    got = check_weights(path)
    assert isinstance(got, str) and len(got) == 64


def test_metadata_nested_too_deeply_stays_a_string(tmp_path):
    deep = "[" * 100_000
    path = _graph(tmp_path, external=False, metadata={"beacons": deep, "window": '{"history": 5}'})
    meta = read_metadata(session(path))
    assert meta["beacons"] == deep and meta["window"] == {"history": 5}
