"""Export a trained localizer to ONNX: ``python export.py ckpt=RUN/last.ckpt out=MODEL.onnx`` (see conf/export.yaml),
or a runtime bundle: ``python export.py bundle=true ckpt=RUN/last.ckpt out=BUNDLE [mapprior=RUN2/last.ckpt]``
(:mod:`blenav.runtime.bundle`). Errors the user can fix print one line (``--debug`` shows the traceback).
The same as ``blenav-export``: :mod:`blenav.cli.export` (the work: :func:`blenav.learn.export.export`,
:func:`blenav.learn.bundle.export_bundle`)."""

from blenav.cli.export import main

if __name__ == "__main__":
    main()
