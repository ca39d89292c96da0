"""``blenav-sim sim=PRESET seed=N out=DIR [duration_s=S] [sessions=K] [first_session=F]``: simulate a
dataset (Hydra); ``first_session=F`` writes sessions F .. F+K-1 of the same seed (the same buildings)."""

from __future__ import annotations

import sys

from omegaconf import DictConfig

from .common import run_hydra


def run(cfg: DictConfig):
    """Plain function behind the CLI (tests call it with a composed config)."""
    from blenav.sim.config import make_sim_config
    from blenav.sim.world import simulate

    sim_cfg = make_sim_config(cfg.sim)
    return simulate(sim_cfg, int(cfg.seed), cfg.out, float(cfg.duration_s), int(cfg.sessions),
                    progress=bool(cfg.get("progress", False)), overwrite=bool(cfg.get("overwrite", False)),
                    first_session=int(cfg.get("first_session", 0)))


def _task(cfg: DictConfig) -> None:
    print(f"wrote {run(cfg)}")


def main(argv: list[str] | None = None) -> None:
    run_hydra("blenav-sim", "sim", _task, sys.argv[1:] if argv is None else list(argv))


if __name__ == "__main__":
    main()
