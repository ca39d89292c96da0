"""Tracing a PyTorch network to ONNX, shared by both exports (the cross-phone localizer,
:mod:`blenav.learn.crossphone.export`, and the map prior, :mod:`blenav.learn.mapprior.export`).

:func:`trace_onnx` runs the TorchScript exporter (the dynamo one needs onnxscript, not a dependency) with its
expected warnings silenced, then :func:`blenav.onnx_io.finish_model` writes the doc strings and metadata and
checks the graph. Parity against PyTorch is each export's own check, measured with
:func:`blenav.onnx_io.max_diff` on sessions from :func:`blenav.onnx_io.session`.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import torch
from torch import nn

from blenav.onnx_io import finish_model

DEFAULT_OPSET = 17


def trace_onnx(net: nn.Module, inputs: tuple, path: str | Path, input_names, output_names, dynamic_axes: dict,
               opset: int = DEFAULT_OPSET, metadata: dict[str, str] | None = None, doc: str = "",
               io_docs: dict[str, str] | None = None) -> Path:
    """Trace ``net(*inputs)`` (eval mode, no grad) to ONNX at ``path`` (its folder created), then
    :func:`~blenav.onnx_io.finish_model` (doc strings, ``metadata`` str -> str, ``onnx.checker``). Returns the
    path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    net = net.eval()
    with warnings.catch_warnings(), torch.no_grad():
        # the TorchScript exporter warns about shape checks traced as constants (input sizes other than the
        # batch are fixed by design), its own deprecation, and LSTM batch sizes (the state is a graph input
        # where it matters, which is the remedy it suggests)
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        warnings.filterwarnings("ignore", message=".*legacy TorchScript-based ONNX export.*")
        warnings.filterwarnings("ignore", message=".*batch_size other than 1.*LSTM.*")
        warnings.filterwarnings("ignore", message="The feature will be removed.*")
        torch.onnx.export(net, tuple(inputs), str(path), input_names=list(input_names),
                          output_names=list(output_names), dynamic_axes=dynamic_axes, opset_version=int(opset),
                          dynamo=False)
    return finish_model(path, metadata, doc, io_docs)


def export_dir(out: str | Path, what: str, files: str) -> Path:
    """The export directory ``out`` of a model that exports to a folder (``what``, e.g. "a map prior"; ``files``: what it
    holds, for the message), created; ValueError for an ``.onnx`` path or an existing file."""
    out = Path(out)
    if out.suffix == ".onnx":
        raise ValueError(f"{what} exports to a directory ({files}), not {out}")
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    return out
