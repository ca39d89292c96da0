"""What a network's config node says about the network it builds, read without building it (no torch): the node of
``conf/model/<name>.yaml`` as a method composes it, or a checkpoint's ``model`` meta. The fingerprint localizer checks
a method's settings with it before anything is trained (:mod:`blenav.localizers.fingerprint`), and the export
describes a checkpoint's graph with it (:mod:`blenav.learn.crossphone.export`)."""

from __future__ import annotations


def states_std(model: dict) -> bool:
    """Whether the network of ``model`` (a node with a ``locnet`` entry) states a std, the graph's ``std_m`` output:
    a LocNet with its std head, or a :class:`~blenav.models.PlaceNet` (the spread of its place scores), as
    :func:`blenav.learn.crossphone.export.output_names` reads it from the built network."""
    loc = model.get("locnet") or {}
    return bool(loc.get("std_head")) or str(loc.get("_target_", "")).endswith("PlaceNet")
