"""``blenav-sim sim=PRESET seed=N out=DIR [duration_s=S] [sessions=K] [first_session=F]``: simulate a
dataset (Hydra); ``first_session=F`` writes sessions F .. F+K-1 of the same seed (the same buildings)."""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig

from blenav.paths import conf_dir
from blenav.configs import register_configs

register_configs()


def run(cfg: DictConfig):
    """Plain function behind the CLI (tests call it with a composed config)."""
    from blenav.sim.config import make_sim_config
    from blenav.sim.world import simulate

    sim_cfg = make_sim_config(cfg.sim)
    return simulate(sim_cfg, int(cfg.seed), cfg.out, float(cfg.duration_s), int(cfg.sessions),
                    progress=bool(cfg.get("progress", False)), overwrite=bool(cfg.get("overwrite", False)),
                    first_session=int(cfg.get("first_session", 0)))


@hydra.main(config_path=str(conf_dir()), config_name="sim", version_base="1.3")
def main(cfg: DictConfig) -> None:
    try:
        out = run(cfg)
    except (ValueError, KeyError) as exc:  # bad settings: say what, without a traceback
        print(f"blenav-sim: error: {exc}", file=sys.stderr)
        sys.exit(1)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
