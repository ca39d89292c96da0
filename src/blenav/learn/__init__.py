"""Learned localization (Roy, chapter 3), one package per model over what they share:

- :mod:`blenav.learn.common`: the Lightning run, step budget and schedule, checkpoint reading, ONNX tracing,
  training reports, sweeps (no model);
- :mod:`blenav.learn.crossphone`: the cross-phone localizer (TransNet + LocNet) on RSSI windows, its baselines;
- :mod:`blenav.learn.mapprior`: the learned map prior;
- :mod:`blenav.learn.fingerprint`: LocNet / TransNet+LocNet on fingerprint windows of real walks;
- the entries over them: :func:`blenav.learn.train.train` (``python train.py``; ``cfg.task`` picks the model),
  :func:`blenav.learn.export.export` (``python export.py``; the checkpoint's kind picks the export),
  :func:`blenav.learn.bundle.export_bundle` (``python export.py bundle=true``: a runtime bundle) and
  :mod:`blenav.learn.reference` (the PyTorch pipeline a runtime bundle of both models must reproduce).
"""
