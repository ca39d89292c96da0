"""Export a trained localizer to ONNX: ``python export.py ckpt=RUN/last.ckpt out=MODEL.onnx`` (see conf/export.yaml).
Errors the user can fix print one line (``--debug`` shows the traceback)."""

import sys

from omegaconf import DictConfig, OmegaConf

from blenav.cli.common import run_hydra


def task(cfg: DictConfig) -> None:
    from blenav.learn.export import export

    for key, what in (("ckpt", "the checkpoint to export: ckpt=RUN/last.ckpt"),
                      ("out", "where to write: out=MODEL.onnx (a directory for a map prior)")):
        if OmegaConf.is_missing(cfg, key):
            raise ValueError(f"name {what}")
    print(f"wrote {export(cfg)}")


def main() -> None:
    run_hydra("export.py", "export", task, sys.argv[1:])


if __name__ == "__main__":
    main()
