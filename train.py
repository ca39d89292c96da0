"""Train a learned localizer from a Hydra config: ``python train.py [overrides]`` (see conf/train.yaml);
``model=NAME`` chooses the network config (conf/model/NAME.yaml), as everywhere. Errors the user can fix
print one line (``--debug`` shows the traceback); an interrupted run resumes from OUT/last.ckpt.
The same as ``blenav-train``: :mod:`blenav.cli.train` (the work: :func:`blenav.learn.train.train`)."""

from blenav.cli.train import main

if __name__ == "__main__":
    main()
