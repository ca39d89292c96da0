"""Export a trained localizer to ONNX: ``python export.py ckpt=RUN/last.ckpt out=MODEL.onnx`` (see conf/export.yaml)."""

import sys

import hydra
from omegaconf import DictConfig

from blenav.learn.export import export
from blenav.paths import conf_dir


@hydra.main(config_path=str(conf_dir()), config_name="export", version_base="1.3")
def main(cfg: DictConfig) -> None:
    try:
        path = export(cfg)
    except (FileNotFoundError, ValueError) as exc:  # wrong checkpoint: say what, without a traceback
        print(f"export: error: {exc}", file=sys.stderr)
        sys.exit(1)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
