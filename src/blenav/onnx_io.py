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
- :func:`blenav_version`: the version written into every export;
- :func:`weights_digest` / :func:`check_weights`: the hash of an export's weights that :func:`finish_model`
  writes into its metadata and every loader checks (below).

Weights hash. Every export carries ``weights_sha256`` (JSON string: hex) and ``weights_sha256_tensors``
(JSON object: tensor name -> first 16 hex of the sha256 of its data) in ``metadata_props``. The weight
tensors are the graph's initializers in graph order, then the ``value`` tensor of each ``Constant`` node in
node order (named by the node's output; the exporter folds small constants such as the input scale into
such nodes). A tensor's data is its values as little-endian bytes in row-major (C) order, i.e.
``onnx.numpy_helper.to_array(t).astype("<" + dtype).tobytes()``, whatever the protobuf field it is stored
in. ``weights_sha256`` is the sha256 of, for every weight tensor in that order, its name in UTF-8, one 0 byte
and its data. :func:`check_weights` recomputes both and refuses a file whose weights differ, naming the
tensors that changed, appeared or disappeared: a corrupted or edited file is caught before it localizes
anything. It is a check of integrity, not of origin: whoever can edit the weights can rewrite the hash.

Writers live in :mod:`blenav.learn.common.onnx_export` (tracing needs PyTorch); readers in :mod:`blenav.runtime`.
Needs numpy; ``onnx`` and ``onnxruntime`` are imported only by the functions that use them.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Sequence

import numpy as np

from blenav.limits import check_file_size, max_model_bytes


#: the exported localizer's per-fix std output (a LocNet with a std head, issue 29), m
STD_OUTPUT = "std_m"
#: the smallest std (m) a fix may state: a foreign graph's smaller (or 1e-9) std is raised to it, so no fix's inverse
#: variance can overwhelm a filter's particles (a sub-decimetre fingerprint fix is not a thing)
MIN_FIX_STD_M = 0.1

def session(path: str | Path, threads: int = 1):
    """onnxruntime session of ``path``: CPU, ``threads`` intra-op threads, 1 inter-op thread, sequential."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = int(threads)
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    if not Path(path).is_file():
        raise FileNotFoundError(f"ONNX model {path} does not exist")
    check_file_size(path, "ONNX model", max_model_bytes(), "BLENAV_MAX_MODEL_MB")  # before onnxruntime parses it
    try:
        return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime's InvalidProtobuf, InvalidGraph, ... (RuntimeError-like, not ValueError)
        first = " ".join(str(exc).split())[:300]
        raise ValueError(f"{path} is not an ONNX model onnxruntime can load (written by export.py?): {first}") from exc


def json_props(values: dict, keys: Sequence[str] | None = None) -> dict[str, str]:
    """``metadata_props`` (str -> JSON str, sorted keys) of ``values`` (only ``keys``, in that order, if given)."""
    return {str(k): json.dumps(values[k], sort_keys=True) for k in (values if keys is None else keys)}


def read_metadata(sess) -> dict:
    """The decoded ``metadata_props`` of an onnxruntime session (see :func:`json_props`); a value that is not JSON
    json can read (nor nested thousands deep, nor an integer of more than 4,300 digits) stays the string it is."""
    out = {}
    for k, v in sess.get_modelmeta().custom_metadata_map.items():
        try:
            out[k] = json.loads(v)
        except (ValueError, RecursionError):  # JSONDecodeError is a ValueError; a RecursionError was a traceback
            out[k] = v
    return out


def finish_model(path: str | Path, metadata: dict[str, str] | None = None, doc: str = "",
                 io_docs: dict[str, str] | None = None) -> Path:
    """Load the ONNX file ``path``, set its doc string, the inputs' and outputs' doc strings (``io_docs``: name
    -> text; None leaves them alone) and ``metadata_props`` (replacing any; plus the weights hash of
    :func:`weights_props`), check it (``onnx.checker``, full) and save it in place. Returns the path."""
    import onnx

    path = Path(path)
    model = onnx.load(str(path))
    if io_docs is not None:
        for v in list(model.graph.input) + list(model.graph.output):
            v.doc_string = io_docs.get(v.name, "")
    model.doc_string = doc
    del model.metadata_props[:]
    for k, v in {**(metadata or {}), **weights_props(model)}.items():
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


WEIGHTS_KEY = "weights_sha256"
WEIGHT_TENSORS_KEY = "weights_sha256_tensors"


def _weight_tensors(model):
    """(name, TensorProto) of every weight of ``model``'s graph: initializers in graph order, then the ``value``
    of each Constant node in node order (named by its output)."""
    import onnx

    out = [(t.name, t) for t in model.graph.initializer]
    for node in model.graph.node:
        if node.op_type == "Constant":
            for a in node.attribute:
                if a.type == onnx.AttributeProto.TENSOR:
                    out.append((node.output[0], a.t))
    return out


def _tensor_bytes(t) -> bytes:
    from onnx import numpy_helper

    a = numpy_helper.to_array(t)
    return np.ascontiguousarray(a, dtype=a.dtype.newbyteorder("<")).tobytes()


def weights_digest(model) -> tuple[str, dict[str, str]]:
    """(``weights_sha256`` hex, {tensor name: first 16 hex of the sha256 of its data}) of an ``onnx.ModelProto``
    (see the module docstring for the exact bytes hashed)."""
    total, per = hashlib.sha256(), {}
    for name, t in _weight_tensors(model):
        data = _tensor_bytes(t)
        total.update(name.encode("utf-8") + b"\0")
        total.update(data)
        per[name] = hashlib.sha256(data).hexdigest()[:16]
    return total.hexdigest(), per


def weights_props(model) -> dict[str, str]:
    """The two ``metadata_props`` entries (JSON strings) of :func:`weights_digest`."""
    digest, per = weights_digest(model)
    return json_props({WEIGHTS_KEY: digest, WEIGHT_TENSORS_KEY: per})


def check_weights(path: str | Path) -> str | None:
    """Recompute the weights hash of the ONNX file ``path`` and compare it with its metadata; returns the hash.
    ValueError naming the tensors that differ (changed, missing, unexpected) when they do not match; a
    UserWarning and None for a file without a recorded hash (exported before blenav recorded one)."""
    import onnx

    path = Path(path)
    try:  # the graph file only: its size is bounded (session), the files it may name beside it are not
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:
        raise ValueError(f"{path} is not an ONNX model (written by export.py?): {str(exc)[:200]}") from exc
    external = [n for n, t in _weight_tensors(model) if t.data_location == onnx.TensorProto.EXTERNAL]
    if external:  # a 134-byte graph naming a 1 GB data file took 2 GB of memory to hash
        raise ValueError(f"{path}: weights {', '.join(external[:5])} are stored in external data files; blenav's "
                         "exports hold their weights in the graph file (whose size is bounded): refused")
    props = {p.key: p.value for p in model.metadata_props}
    if WEIGHTS_KEY not in props:
        warnings.warn(f"{path} records no hash of its weights (exported before blenav wrote one): its integrity "
                      "cannot be checked; export it again with `python export.py`", UserWarning, stacklevel=2)
        return None
    try:
        want = json.loads(props[WEIGHTS_KEY])
        want_per = json.loads(props.get(WEIGHT_TENSORS_KEY, "{}"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: metadata {WEIGHTS_KEY!r} is not the JSON blenav writes: {exc}") from None
    digest, per = weights_digest(model)
    if digest == want:
        return digest
    changed = [n for n in per if n in want_per and per[n] != want_per[n]]
    missing = [n for n in want_per if n not in per]
    extra = [n for n in per if n not in want_per]

    def few(names):
        return ", ".join(names[:5]) + (f", ... ({len(names) - 5} more)" if len(names) > 5 else "")

    parts = [f"{len(changed)} of {len(want_per)} weight tensors changed ({few(changed)})"] if changed else []
    parts += [f"tensors missing: {few(missing)}"] if missing else []
    parts += [f"tensors not in the export: {few(extra)}"] if extra else []
    if not parts:
        parts = ["the tensors' names or order differ"]
    raise ValueError(f"{path}: its weights are not the ones it was exported with ({'; '.join(parts)}; "
                     f"{WEIGHTS_KEY} recorded {str(want)[:16]}..., computed {digest[:16]}...): the file was "
                     "corrupted or edited after export; export it again from its checkpoint (python export.py "
                     "ckpt=RUN/last.ckpt out=...) or get an intact copy")


def check_export_files(root: Path, meta: dict, names, meta_name: str = "meta.json") -> None:
    """Refuse an export directory whose graphs ``names`` are not the ones written with its ``meta_name``: each graph's
    weights against the hash in its own metadata (:func:`check_weights`, naming the tensors that changed), then each
    file against the sha256 the meta records for it (any other change: graph, metadata). An export without recorded
    hashes (older blenav) is checked by its weights only."""
    import hashlib

    recorded = meta.get("sha256") or {}
    for name in names:
        path = Path(root) / name
        check_weights(path)
        want = recorded.get(name)
        if want is None:
            continue
        got = hashlib.sha256(path.read_bytes()).hexdigest()
        if got != want:
            raise ValueError(f"{path} is not the file exported with {Path(root) / meta_name} (sha256 recorded "
                             f"{want[:16]}..., file {got[:16]}...; its weights are intact, so its graph or metadata "
                             "was changed after export): export the directory again with `python export.py "
                             "ckpt=RUN/last.ckpt out=DIR`")
