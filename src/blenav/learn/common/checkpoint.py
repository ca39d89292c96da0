"""Reading blenav checkpoints of every task (the cross-phone localizer, the map prior), safely, and the one hash of
training data stored in them.

Every Lightning checkpoint ``train(cfg)`` writes carries a ``"blenav"`` entry (:data:`KEY`), the meta its task
rebuilds its networks from with no config file beside the checkpoint (:mod:`blenav.learn.crossphone.checkpoint`,
:mod:`blenav.learn.mapprior.checkpoint`). :func:`read_checkpoint` is the one place such a file is read (both tasks'
loaders, the resume of a run and the evaluation use it); :func:`data_hash` the one hash of training data stored in
them.

Files from strangers. A checkpoint is a pickle, and unpickling runs whatever callables the file names.
:func:`load_file` therefore reads with ``torch.load(..., weights_only=True)``: torch's restricted unpickler
builds tensors, dicts, lists, tuples, str, numbers, bool and None and nothing else, plus the types in
:data:`SAFE_GLOBALS` (handed to ``torch.serialization.safe_globals``). A file that names anything else is
refused with :class:`UnsafeCheckpointError` (naming the file and the callables it asks for) before any of
them runs. Resuming a run (:func:`blenav.learn.common.trainer.fit`) reads the file with it first.

The meta is data too, yet its ``model`` node names with ``_target_`` the classes to build. :func:`load_file`
(every read: the tasks' loaders, the export, the resume of a run) therefore checks every ``_target_`` of the meta,
at any depth, against :data:`blenav.trust.TARGETS` by name, before Hydra imports anything, and each task's network
builder (:func:`blenav.learn.crossphone.checkpoint.build_networks`, :func:`blenav.learn.mapprior.checkpoint.build_net`)
checks the node it builds again: a checkpoint that names another callable (``numpy.savetxt`` deep inside
``locnet``) is refused with :class:`blenav.trust.UntrustedTargetError`, naming the file and the key path, and
nothing of it runs.
"""

from __future__ import annotations

import hashlib
import pickle
import pickletools
import re
import zipfile
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
import torch

from blenav.trust import check_targets

KEY = "blenav"

#: Types a blenav checkpoint may hold beyond what ``torch.load(weights_only=True)`` accepts by itself, for
#: ``torch.serialization.safe_globals`` (a class or function, or ``(obj, "module.Name")``). Measured with
#: ``torch.serialization.get_unsafe_globals_in_checkpoint`` on every kind of checkpoint train.py writes
#: (LocNet, TransNet+LocNet, DL-RNN, scenario 3 with its semi-supervised stage, the map prior with early
#: stopping; Lightning 2.6, torch 2.13): they hold tensors, dicts, lists, str, numbers, bool and None only,
#: so nothing needs allowing and the list is empty (tests/learn/test_checkpoint.py keeps it that way: a
#: type added to a checkpoint fails there first). Add a type only if rebuilding it cannot run code.
SAFE_GLOBALS: tuple = ()


class UnsafeCheckpointError(ValueError):
    """A checkpoint that would run code (or build objects blenav never writes) when unpickled: refused."""


def data_hash(*arrays: np.ndarray) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def _unsafe_globals(path: Path) -> list[str] | None:
    """The callables the pickle of ``path`` names outside torch's allow-list and :data:`SAFE_GLOBALS`, read from
    its opcodes (nothing is executed): torch's own scan for a zip checkpoint, :mod:`pickletools` for a bare
    (legacy) pickle. None when ``path`` is not a pickle at all."""
    if zipfile.is_zipfile(path):
        try:
            names = list(torch.serialization.get_unsafe_globals_in_checkpoint(path))
        except Exception:  # a damaged archive: the message does without the names
            return []
    else:
        names = _legacy_globals(path)
        if names is None:
            return None
        try:  # torch's default allow-list (private, hence the guard): only what it would refuse is named
            from torch._weights_only_unpickler import _get_allowed_globals

            allowed = set(_get_allowed_globals())
        except Exception:
            allowed = set()
        names = [n for n in names if n not in allowed]
    mine = {g[1] if isinstance(g, tuple) else f"{g.__module__}.{g.__qualname__}" for g in SAFE_GLOBALS}
    return list(dict.fromkeys(n for n in names if n not in mine))


def _legacy_globals(path: Path) -> list[str] | None:
    """``module.name`` of every GLOBAL / STACK_GLOBAL in the pickles at the start of ``path`` (torch's legacy
    format is several pickles, then raw storage bytes); None when not even the first one parses."""
    names: list[str] = []
    parsed = False
    with open(path, "rb") as f:
        while True:
            strings: list[str] = []
            try:
                for op, arg, _ in pickletools.genops(f):
                    if op.name == "GLOBAL":
                        names.append(str(arg).replace(" ", "."))
                    elif op.name == "STACK_GLOBAL" and len(strings) >= 2:
                        names.append(f"{strings[-2]}.{strings[-1]}")
                    if isinstance(arg, str):
                        strings.append(arg)
            except Exception:  # not a pickle (or the raw storage bytes after the pickles)
                break
            parsed = True
            if not f.read(1):
                break
            f.seek(-1, 1)
    return names if parsed else None


def _refusal(path: Path, names: list[str], detail: str = "") -> UnsafeCheckpointError:
    what = f"it asks the unpickler to call {', '.join(names[:5])}{', ...' if len(names) > 5 else ''}" if names \
        else f"it holds objects other than tensors, numbers, strings, lists and dicts ({detail})"
    return UnsafeCheckpointError(
        f"{path}: refused to load this checkpoint: {what}, which blenav's checkpoints never contain; unpickling "
        "it could run code of whoever made the file. Load only checkpoints written by `python train.py` (from a "
        "source you trust, ask for the exported .onnx model instead: it carries no code)")


def load_file(path: str | Path) -> dict:
    """``torch.load(path, map_location="cpu", weights_only=True)`` with :data:`SAFE_GLOBALS` allowed.
    FileNotFoundError without the file; :class:`UnsafeCheckpointError` for a pickle that would build
    anything else (nothing of it runs); ValueError for a file that is not a PyTorch checkpoint;
    :class:`blenav.trust.UntrustedTargetError` when its ``"blenav"`` meta names (``_target_``, at any depth) a
    class blenav does not build from configs -- the resume of a run reads the file here too."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        with torch.serialization.safe_globals(list(SAFE_GLOBALS)):
            ck = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:  # the restricted unpickler stopped before building the object
        m = re.search(r"WeightsUnpickler error:\s*(.+?)(\n\n|$)", str(exc), re.S)
        detail = " ".join((m.group(1) if m else str(exc).split("\n")[0]).split())[:200]
        names = _unsafe_globals(path)
        if names is None:  # not a pickle: junk, not a threat
            raise _unreadable(path, detail) from None
        raise _refusal(path, names, detail) from None
    except Exception as exc:  # not a zip/pickle, truncated, ... (torch raises RuntimeError, KeyError, EOFError)
        raise _unreadable(path, f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}") from None
    if isinstance(ck, dict) and KEY in ck:
        # the meta may name nothing but blenav's classes, as written (no resolver runs on a foreign file), and holds
        # no interpolation at all (_check_plain): nothing in it can resolve into a node no check saw
        check_targets(ck[KEY], f"checkpoint {path}", prefix=KEY, resolve=False)
        _check_plain(ck[KEY], path)
    return ck


def _check_plain(meta, path: Path) -> None:
    """The meta holds resolved values only: no ``${...}`` interpolation (Hydra resolves a node before it builds it,
    and ``${oc.create:{_target_: numpy.savetxt, ...}}`` in a size would build a node no check saw: it wrote its
    file) and no ``_partial_`` (a network would be a factory). A ValueError naming the checkpoint and the key."""
    stack = [(meta, KEY)]
    while stack:
        n, where = stack.pop()
        if isinstance(n, str) and "${" in n:
            raise ValueError(f"checkpoint {path}: {where} = {n[:80]!r} is an interpolation; train.py writes resolved "
                             "values only, so this file was edited: refused")
        if isinstance(n, dict):
            if "_partial_" in n:
                raise ValueError(f"checkpoint {path}: {where}._partial_ is set; train.py never writes it: refused")
            stack.extend((v, f"{where}.{k}") for k, v in n.items())
        elif isinstance(n, (list, tuple)):
            stack.extend((v, f"{where}[{i}]") for i, v in enumerate(n))


def check_weight_shapes(build: Callable[[], Mapping[str, object]], state_dict: Mapping, where: str,
                        what: str) -> None:
    """The networks a checkpoint's meta describes have exactly the checkpoint's weights, checked before they are built
    for real: ``build()`` (run under ``torch.device("meta")``: nothing is allocated) returns {state-dict prefix:
    network or None} from the meta's sizes; every parameter and buffer under those prefixes must match the weights
    by name and shape. A meta that claims other sizes (2,000,000 beacons, hidden = 10**7, a U-Net of 60,000
    channels) is one ValueError naming ``where`` (the checkpoint) and ``what`` (the meta fields the sizes come
    from), instead of allocating gigabytes for weights that cannot load; so is a size the classes refuse (negative,
    not an integer)."""
    from hydra.errors import InstantiationException

    try:
        with torch.device("meta"):
            nets = build()
    except (InstantiationException, RuntimeError, TypeError, OverflowError) as exc:
        why = " ".join(str(exc).split()) or type(exc).__name__
        raise ValueError(f"{where}: {what} build no network: {why[:300]}") from None
    shapes = {f"{k}.{n}": tuple(t.shape) for k, net in nets.items() if net is not None
              for n, t in net.state_dict().items()}
    prefixes = tuple(f"{k}." for k in nets)
    have = {k: tuple(v.shape) for k, v in state_dict.items() if k.startswith(prefixes)}
    for k in sorted(set(shapes) | set(have)):
        if shapes.get(k) != have.get(k):
            raise ValueError(f"{where}: {what} ask for {k} of shape {shapes.get(k)}, the weights have {have.get(k)}; "
                             "the meta does not describe these weights")


def _unreadable(path: Path, detail: str) -> ValueError:
    return ValueError(f"{path} is not a PyTorch checkpoint torch can read (damaged, truncated, or another kind of "
                      f"file; write it with `python train.py`): {detail}")


def read_checkpoint(path: str | Path, what: str = "blenav", require_meta: bool = True) -> dict:
    """The whole checkpoint dict of ``path`` (state dict, optimizer states, counters, the ``"blenav"`` meta),
    on the CPU, read by :func:`load_file` (weights only: a file that would run code, or whose meta names a class
    that is not blenav's, is refused).
    FileNotFoundError without the file; ValueError when ``require_meta`` and it has no ``"blenav"`` entry
    (``what`` names the expected kind in the message)."""
    path = Path(path)
    ck = load_file(path)
    if not isinstance(ck, dict):
        raise ValueError(f"{path}: not a {what} checkpoint (a {type(ck).__name__}, not a dict); was it written by "
                         "train.py?")
    if require_meta and KEY not in ck:
        raise ValueError(f"{path}: not a {what} checkpoint (no '{KEY}' entry); was it written by train.py?")
    if KEY in ck and not isinstance(ck[KEY], dict):
        raise ValueError(f"{path}: not a {what} checkpoint ('{KEY}' is a {type(ck[KEY]).__name__}, not a table)")
    return ck


def read_meta(path: str | Path) -> dict:
    """The ``"blenav"`` meta of a checkpoint of either task (its ``kind``: none for a cross-phone localizer,
    ``mapprior`` for a map prior)."""
    return read_checkpoint(path, "blenav cross-phone")[KEY]
