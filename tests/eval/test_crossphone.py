"""blenav-eval experiment=crossphone_003: every method on one split, per-device tables, reuse of runs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from blenav.configs import compose
from blenav.errors import EvalError
from blenav.eval.harness import evaluate
from helpers import simulate_small

PHONES = ["iphone-8", "galaxy-s10", "mi-9", "pixel-4xl"]
KEYS = {"LocNet", "LocNet+aug", "TransNet+LocNet", "TransNet+LocNet+semi", "DL-RNN", "KNN", "Bayesian", "KRR+KF"}


@pytest.fixture(scope="module")
def four_phones(tmp_path_factory):
    out = tmp_path_factory.mktemp("cp") / "d"
    simulate_small(out, 11, 60, 8, f"sim.receivers=[{','.join(PHONES)}]", "sim.unlabelled_every=0")
    return out


def cfg(data, out, *extra):
    return compose("eval", "experiment=crossphone_003", f"data={data}", f"out={out}", "progress=false",
                   "data.train_devices=[iphone-8,galaxy-s10]", "data.known_devices=[iphone-8]",
                   "data.unlabelled_devices=[mi-9]", "data.batch_size=64", "trainer.max_epochs=1",
                   "trainer.enable_progress_bar=false", "experiment.learned.semi.semi.epochs=1",
                   "experiment.baselines.krr_kf.n_components=50", *extra)


def test_every_method_is_scored_per_device_on_the_same_windows(four_phones, tmp_path):
    res = evaluate(cfg(four_phones, tmp_path / "o"))
    assert set(res["methods"]) == KEYS
    assert res["split"]["train"] == ["galaxy-s10", "iphone-8"] and res["split"]["unlabelled"] == ["mi-9"]
    n = {m["n_windows"] for m in res["methods"].values()}
    assert len(n) == 1  # the same test windows for every method
    for name, m in res["methods"].items():
        assert set(m["per_device"]) == set(PHONES), name  # trained phones give held-out sessions, mi-9 half of its
        for d, st in m["per_device"].items():
            assert {"mean", "std", "median", "p90", "max"} <= set(st) and np.isfinite(st["mean"]), (name, d)
        assert m["error_m"]["max"] >= m["error_m"]["p90"] >= m["error_m"]["median"] > 0
    assert not set(res["train_sessions"]) & set(res["sessions"])  # no session on both sides
    assert res["methods"]["LocNet"]["training"]["batch_size"] == 64  # the given batch, reported beside the steps
    import torch

    semi = torch.load(tmp_path / "o" / "runs" / "semi" / "last.ckpt", map_location="cpu", weights_only=True)
    base = torch.load(tmp_path / "o" / "runs" / "transnet_locnet" / "last.ckpt", map_location="cpu", weights_only=True)
    assert semi["epoch"] == base["epoch"] + 1  # scenario 3 continued scenario 2's run into last.ckpt
    assert not torch.equal(semi["state_dict"]["locnet.head.2.weight"], base["state_dict"]["locnet.head.2.weight"])
    on_disk = json.loads((tmp_path / "o" / "results.json").read_text())
    assert on_disk["methods"]["KNN"]["per_device"]["pixel-4xl"]["mean"] == pytest.approx(
        res["methods"]["KNN"]["per_device"]["pixel-4xl"]["mean"])
    md = (tmp_path / "o" / "results.md").read_text()
    assert "Table 3.3" in md and "Table 3.5" in md and "pixel-4xl" in md
    assert (tmp_path / "o" / "per_device.png").is_file() and (tmp_path / "o" / "error_cdf.png").is_file()
    # a second evaluation reuses the finished training runs (same data hash) and gives the same numbers
    again = evaluate(cfg(four_phones, tmp_path / "o", "plots=false"))
    assert again["methods"]["LocNet"]["error_m"]["mean"] == pytest.approx(res["methods"]["LocNet"]["error_m"]["mean"])
    assert res["methods"]["LocNet"]["source"].startswith("trained") and again["methods"]["LocNet"]["source"].startswith("reused")


def test_runs_trained_on_other_data_are_refused(four_phones, tmp_path):
    only_locnet = ["plots=false", "~experiment.baselines", "~experiment.learned.semi", "~experiment.learned.dlrnn",
                   "~experiment.learned.transnet_locnet", "~experiment.learned.locnet_aug"]
    res = evaluate(cfg(four_phones, tmp_path / "o", *only_locnet))
    assert set(res["methods"]) == {"LocNet"}
    with pytest.raises(EvalError, match="trained on other data"):
        evaluate(cfg(four_phones, tmp_path / "o", *only_locnet, "data.train_devices=[iphone-8]"))
    # same data, another model config (here the receiver augmentation): refused too, not silently reused
    with pytest.raises(EvalError, match="another model config.*augment"):
        evaluate(cfg(four_phones, tmp_path / "o", *only_locnet, "experiment.learned.locnet.model.augment.offset_db_std=3"))


def test_unknown_device_is_named(four_phones, tmp_path):
    with pytest.raises(EvalError, match="nokia"):
        evaluate(cfg(four_phones, tmp_path / "o", "data.test_devices=[nokia]"))
