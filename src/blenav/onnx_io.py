"""What every ONNX file of blenav shares, in one place and without PyTorch: onnxruntime sessions, the
``metadata_props`` written into an export and read back, and the parity measure of an export check.

- :func:`session`: an ``onnxruntime.InferenceSession`` on the CPU with ``threads`` intra-op threads, one
  inter-op thread and sequential execution (what a phone app runs; every loader and every export check uses
  these settings, so a parity check measures the graph the runtime will run);
- :func:`json_props` / :func:`read_metadata`: ``metadata_props`` are str -> str; blenav stores every value as
  JSON (``sort_keys``) and decodes it on reading (a value that is not JSON stays a string);
- :func:`finish_model`: after tracing, give the graph its doc strings and metadata (replacing any), run
  ``onnx.checker`` (full check) and save it;
- :func:`max_diff`: the largest difference between an export's outputs and the reference's (absolute, or
  relative to the reference's scale when that exceeds 1);
- :func:`blenav_version`: the version written into every export.

Writers live in :mod:`blenav.learn.onnx_export` (tracing needs PyTorch); readers in :mod:`blenav.runtime`.
Needs numpy; ``onnx`` and ``onnxruntime`` are imported only by the functions that use them.
"""

from __future__ import annotations

import json
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Sequence

import numpy as np


def session(path: str | Path, threads: int = 1):
    """onnxruntime session of ``path``: CPU, ``threads`` intra-op threads, 1 inter-op thread, sequential."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = int(threads)
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    if not Path(path).is_file():
        raise FileNotFoundError(f"ONNX model {path} does not exist")
    try:
        return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime's InvalidProtobuf, InvalidGraph, ... (RuntimeError-like, not ValueError)
        first = " ".join(str(exc).split())[:300]
        raise ValueError(f"{path} is not an ONNX model onnxruntime can load (written by export.py?): {first}") from exc


def json_props(values: dict, keys: Sequence[str] | None = None) -> dict[str, str]:
    """``metadata_props`` (str -> JSON str, sorted keys) of ``values`` (only ``keys``, in that order, if given)."""
    return {str(k): json.dumps(values[k], sort_keys=True) for k in (values if keys is None else keys)}


def read_metadata(sess) -> dict:
    """The decoded ``metadata_props`` of an onnxruntime session (see :func:`json_props`)."""
    out = {}
    for k, v in sess.get_modelmeta().custom_metadata_map.items():
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def finish_model(path: str | Path, metadata: dict[str, str] | None = None, doc: str = "",
                 io_docs: dict[str, str] | None = None) -> Path:
    """Load the ONNX file ``path``, set its doc string, the inputs' and outputs' doc strings (``io_docs``: name
    -> text; None leaves them alone) and ``metadata_props`` (replacing any), check it (``onnx.checker``, full)
    and save it in place. Returns the path."""
    import onnx

    path = Path(path)
    model = onnx.load(str(path))
    if io_docs is not None:
        for v in list(model.graph.input) + list(model.graph.output):
            v.doc_string = io_docs.get(v.name, "")
    model.doc_string = doc
    del model.metadata_props[:]
    for k, v in (metadata or {}).items():
        model.metadata_props.add(key=str(k), value=str(v))
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, str(path))
    return path


def max_diff(got: Sequence[np.ndarray], ref: Sequence[np.ndarray], relative: bool = False) -> float:
    """max over output pairs of max |got - ref| (0 for empty outputs); ``relative``: each divided by
    max(1, max |ref|), so outputs larger than 1 are compared at their own scale."""
    worst = 0.0
    for a, b in zip(got, ref):
        a, b = np.asarray(a), np.asarray(b)
        if not a.size:
            continue
        d = np.max(np.abs(a - b))
        if relative:
            d = d / max(1.0, float(np.max(np.abs(b))))
        worst = max(worst, float(d))
    return worst


def blenav_version() -> str:
    """The installed blenav's version (the package's ``__version__`` when it is not installed)."""
    try:
        return importlib_metadata.version("blenav")
    except importlib_metadata.PackageNotFoundError:
        from blenav import __version__

        return __version__
