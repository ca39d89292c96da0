"""Issue 28, section 2: every size a setting sets is bounded before the work (blenav.limits): a value outside its
documented range, or a filter whose memory estimate exceeds BLENAV_MAX_MEMORY_GB, is one line naming the file or
config and the field, never a MemoryError traceback or numpy's message."""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np
import pytest

from blenav import limits
from blenav.filters.engine import FilterConfig, Initializer, ParticleFilter, memory_bytes
from blenav.filters.motion import OdometryIncrement, RandomWalk
from blenav.limits import RANGES, LimitError, MemoryLimitError, check_memory, check_range


def _one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg, msg
    return msg


# --- the helpers -------------------------------------------------------------------------------------------

def test_check_range_returns_the_value_and_names_the_field():
    assert check_range(300, "n_particles", "w") == 300 and isinstance(check_range(300.0, "n_particles", "w"), int)
    assert check_range(2.5, "rate_hz", "w") == 2.5
    for bad, words in ((0, "= 0 is outside [1, 10,000,000]"), (2.5, "= 2.5 is not a whole number"),
                       ("many", "= 'many' is not a number"), (True, "= True is not a number"),
                       (float("nan"), "= nan is outside")):
        with pytest.raises(LimitError) as e:
            check_range(bad, "n_particles", "cfg.yaml", field="filter.n_particles")
        assert _one_line(e).startswith(f"cfg.yaml: filter.n_particles {words}"), str(e.value)
    assert RANGES["runs"].hi == 100_000 and RANGES["n_particles"].hi == 10_000_000


def test_memory_limit_comes_from_the_environment(monkeypatch):
    check_memory(7.9 * 2**30, "x", "w")  # under the default 8 GiB
    with pytest.raises(MemoryLimitError) as e:
        check_memory(9 * 2**30, "a thing", "w")
    assert _one_line(e) == ("w: a thing needs about 9 GiB, above the limit of 8 GiB (set BLENAV_MAX_MEMORY_GB to "
                            "allow more)")
    monkeypatch.setenv("BLENAV_MAX_MEMORY_GB", "16")
    check_memory(9 * 2**30, "a thing", "w")
    monkeypatch.setenv("BLENAV_MAX_MEMORY_GB", "lots")
    with pytest.raises(LimitError, match="BLENAV_MAX_MEMORY_GB='lots': expected a positive number"):
        check_memory(1, "a thing", "w")


# --- the particle filter engine ----------------------------------------------------------------------------

class _Init(Initializer):
    def sample(self, rng, R, N):
        return rng.normal(size=(R, N, 2))


@pytest.mark.parametrize("n", [1e9, -5, 0])
def test_engine_refuses_particle_counts_outside_the_range(n):
    with pytest.raises(LimitError) as e:  # 1e9 asked numpy for 37 GiB (MemoryError); -5, 0: numpy's messages
        ParticleFilter(FilterConfig(n_particles=n), RandomWalk(), [], _Init(), np.random.default_rng(0))
    assert _one_line(e) == f"filter settings: n_particles = {n!r} is outside [1, 10,000,000] (particles per run)"


def test_engine_refuses_runs_times_particles_over_the_memory_limit():
    # each in range, together 1e9 particles of 4 values: 8 bytes x (2 x 4 + 8) arrays = 119 GiB
    assert memory_bytes(1000, 1_000_000, 4) == 1e9 * 8 * 16
    with pytest.raises(MemoryLimitError) as e:
        ParticleFilter(FilterConfig(n_particles=1_000_000), RandomWalk(), [], _Init(), np.random.default_rng(0),
                       n_runs=1000)
    assert _one_line(e) == ("filter settings: n_particles 1,000,000 x 1,000 run(s) x 4 state values needs about "
                            "119 GiB, above the limit of 8 GiB (set BLENAV_MAX_MEMORY_GB to allow more)")
    with pytest.raises(LimitError, match="filter settings: runs = 0 is outside"):
        ParticleFilter(FilterConfig(), RandomWalk(), [], _Init(), np.random.default_rng(0), n_runs=0)


def test_engine_legitimate_sizes_are_unchanged():
    pf = ParticleFilter(FilterConfig(n_particles=300.0), RandomWalk(), [], _Init(), np.random.default_rng(0), n_runs=3)
    assert (pf.R, pf.N) == (3, 300) and isinstance(pf.N, int) and pf.x.shape == (3, 300, 4)


# --- a bundle's settings.json ------------------------------------------------------------------------------

def _bundle(tmp_path, **filt):
    """A bundle folder whose settings.json sets ``filt`` (manifest re-hashed, as a tamperer would); no graph: the
    settings are refused before any is loaded."""
    from blenav.runtime.bundle import DEFAULT_SETTINGS, FORMAT, MANIFEST, SETTINGS

    root = tmp_path / "bundle"
    root.mkdir()
    settings = json.loads(json.dumps(DEFAULT_SETTINGS))
    settings["filter"].update(filt)
    (root / SETTINGS).write_text(json.dumps(settings))
    sha = hashlib.sha256((root / SETTINGS).read_bytes()).hexdigest()
    (root / MANIFEST).write_text(json.dumps({"format": FORMAT, "files": {SETTINGS: {"sha256": sha}}}))
    return root


@pytest.mark.parametrize("n", [1e9, -5, 0])
def test_bundle_settings_out_of_range_name_settings_json_and_the_field(tmp_path, n):
    from blenav.runtime.bundle import Bundle

    root = _bundle(tmp_path, n_particles=n)
    with pytest.raises(LimitError) as e:
        Bundle.open(root, verify=False)
    assert _one_line(e).startswith(f"{root / 'settings.json'}: filter.n_particles = {n!r} is outside [1, 10,000,000]")


def test_bundle_settings_memory_refused_with_the_number(tmp_path, monkeypatch):
    from blenav.runtime.bundle import Bundle

    monkeypatch.setenv("BLENAV_MAX_MEMORY_GB", "0.5")
    root = _bundle(tmp_path, n_particles=5_000_000)  # in range; one run of OdometryIncrement's 5 values: 0.67 GiB
    assert OdometryIncrement.state_dim == 5
    with pytest.raises(MemoryLimitError) as e:
        Bundle.open(root, verify=False)
    assert _one_line(e) == (f"{root / 'settings.json'}: filter.n_particles 5,000,000 x 1 run(s) x 5 state values "
                            "needs about 0.671 GiB, above the limit of 0.5 GiB (set BLENAV_MAX_MEMORY_GB to allow more)")


def test_bundle_settings_rates_and_windows_are_bounded(tmp_path):
    from blenav.runtime.bundle.settings import check_settings

    with pytest.raises(LimitError, match=r"S: filter.rate_hz = 0 is outside \[0.001, 1,000\] Hz"):
        check_settings({"filter": {"rate_hz": 0}, "motion": {}}, "S")
    with pytest.raises(LimitError, match="S: prior.heading_bins = 1000000000000.0 is outside"):
        check_settings({"prior": {"heading_bins": 1e12}}, "S")
    with pytest.raises(LimitError, match="S: prior.window_dt_s = -1 is outside"):
        check_settings({"prior": {"window_dt_s": -1}}, "S")
    from blenav.runtime.bundle import DEFAULT_SETTINGS

    check_settings(json.loads(json.dumps(DEFAULT_SETTINGS)), "S")  # the shipped settings pass


@pytest.mark.parametrize("node, key, value, words", [
    ("fix", "sigma_m", "x", "is not a number"), ("fix", "sigma_m", float("nan"), "is not a number"),
    ("fix", "sigma_m", -3, "is negative"), ("filter", "ess_threshold", "x", "is not a number"),
    ("filter", "divergence_sigma", "x", "is not a number"), ("filter", "reinit_radius_m", float("inf"), "is infinite"),
    ("map", "init_sigma_m", float("nan"), "is not a number"), ("motion", "sigma2_per_s", -1, "is negative"),
    ("motion", "sigma_theta", True, "is not a number")])
def test_bundle_settings_other_numbers_name_settings_json_and_the_field(node, key, value, words):
    """Red-team (issue 28): a string, NaN, a negative or an infinite noise scale elsewhere in settings.json was a
    traceback (numpy's isfinite / 'less' on a str) or a NaN track ending in 'cannot convert float NaN to integer'
    with no file named; now one LimitError naming settings.json and the field, before anything is built."""
    from blenav.runtime.bundle import DEFAULT_SETTINGS
    from blenav.runtime.bundle.settings import check_settings

    settings = json.loads(json.dumps(DEFAULT_SETTINGS))
    settings[node][key] = value
    with pytest.raises(LimitError) as e:
        check_settings(settings, "B/settings.json")
    assert _one_line(e).startswith(f"B/settings.json: {node}.{key} = {value!r} {words}")


# --- the CRF grid and eval runs ----------------------------------------------------------------------------

def test_crf_cell_size_and_grid_memory_are_bounded(monkeypatch):
    from blenav.crf.grid import grid_from_occupancy
    from blenav.limits import MemoryLimitError
    from blenav.localizers.crf import CrfLocalizer

    with pytest.raises(LimitError, match=r"method 'CRF': cell_m = 0.0001 is outside \[0.01, 100\] m"):
        CrfLocalizer("CRF", cell_m=1e-4)
    with pytest.raises(LimitError, match="method 'CRF': max_step_m = 5000.0 is outside"):
        CrfLocalizer("CRF", max_step_m=5000.0)
    occ = np.zeros((200, 300), np.int8)  # a 20 x 30 m free floor at 0.1 m/px
    g = grid_from_occupancy(occ, 0.1, (0.0, 0.0), 0.5, 2.0)
    assert g.shape == (40, 60)
    monkeypatch.setenv("BLENAV_MAX_MEMORY_GB", "0.01")
    with pytest.raises(MemoryLimitError) as e:
        grid_from_occupancy(occ, 0.1, (0.0, 0.0), 0.05, 2.0)  # 400 x 600 cells, 5,000 offsets each
    assert _one_line(e).startswith("crf grid (cell_m, max_step_m): a grid of 400 x 600 cells of 0.05 m with steps "
                                   "up to 2 m needs about ")


@pytest.mark.parametrize("runs, words", [(0, "runs = 0 is outside [1, 100,000]"),
                                         (1e9, "runs = 1000000000 is outside [1, 100,000]")])
def test_eval_runs_are_bounded(tiny_dataset, tmp_path, runs, words):
    from blenav.configs import compose
    from blenav.errors import EvalError
    from blenav.eval.harness import evaluate

    cfg = compose("eval", "progress=false", "experiment=mapfusion_002", f"data={tiny_dataset}", f"runs={runs}",
                  f"out={tmp_path / 'o'}", "plots=false", "calibration=none")
    with pytest.raises(EvalError) as e:
        evaluate(cfg)
    assert _one_line(e) == f"eval config: {words} (independent runs of a filter per session)"


def test_bundle_metadata_files_are_size_checked_before_reading(tmp_path, monkeypatch):
    """A manifest or settings.json padded to megabytes is refused by its size, naming the file, before json reads it;
    a settings.json that is not an object is refused in one line."""
    from blenav.runtime.bundle import MANIFEST, SETTINGS, Bundle

    root = _bundle(tmp_path, n_particles=100)
    monkeypatch.setenv("BLENAV_MAX_JSON_MB", "0.001")  # 1 kB
    (root / MANIFEST).write_text(json.dumps({"format": "x", "pad": "x" * 5000}))
    n = (root / MANIFEST).stat().st_size
    with pytest.raises(LimitError) as e:
        Bundle.open(root, verify=False)
    assert _one_line(e).startswith(f"{root / MANIFEST}: manifest file of {n:,} bytes, above the limit of 1,048 bytes")
    monkeypatch.delenv("BLENAV_MAX_JSON_MB")
    (tmp_path / "b2").mkdir()
    root = _bundle(tmp_path / "b2", n_particles=100)
    (root / SETTINGS).write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"settings.json: not a settings object, a list"):
        Bundle.open(root, verify=False)
    (root / SETTINGS).write_text("{\"filter\": ")
    with pytest.raises(ValueError, match=r"settings.json: not JSON \(Expecting value: line 1 column 12\)"):
        Bundle.open(root, verify=False)


def test_onnx_model_size_is_checked_before_onnxruntime_reads_it(tmp_path, monkeypatch):
    from blenav.onnx_io import session

    p = tmp_path / "big.onnx"
    p.write_bytes(b"\0" * 4096)
    monkeypatch.setenv("BLENAV_MAX_MODEL_MB", "0.001")
    with pytest.raises(LimitError) as e:
        session(p)
    assert _one_line(e) == (f"{p}: ONNX model file of 4,096 bytes, above the limit of 1,048 bytes "
                            "(set BLENAV_MAX_MODEL_MB, in MiB, to allow more)")
    monkeypatch.setenv("BLENAV_MAX_MODEL_MB", "1")
    with pytest.raises(ValueError, match="is not an ONNX model onnxruntime can load"):  # size fine: onnxruntime's turn
        session(p)


def test_read_json_names_the_file_for_a_huge_integer(tmp_path):
    """Red-team (issue 28 sec. 4): a manifest.json holding a 5,000-digit integer ended as Python's own 'Exceeds the
    limit (4300 digits) ...' with no file named; now the message starts with the file."""
    from blenav.limits import read_json

    p = tmp_path / "manifest.json"
    p.write_text('{"format": ' + "1" * 5000 + "}")
    with pytest.raises(ValueError) as e:
        read_json(p, "manifest")
    assert _one_line(e).startswith(f"{p}: not readable JSON (Exceeds the limit (4300 digits)")


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero on this system")
def test_read_json_stops_reading_past_its_limit(monkeypatch):
    """The size is that of the file opened and the read itself stops past the limit: a file whose stated size says
    nothing (/dev/zero states 0 bytes; a file still growing after the check) was read on without end."""
    from blenav.limits import read_json

    monkeypatch.setenv("BLENAV_MAX_JSON_MB", "0.001")  # 1 kB
    with pytest.raises(LimitError) as e:
        read_json("/dev/zero", "settings")
    assert _one_line(e) == ("/dev/zero: settings file of 1,049 bytes, above the limit of 1,048 bytes "
                            "(set BLENAV_MAX_JSON_MB, in MiB, to allow more)")


@pytest.mark.realdata
def test_the_archive_numbers_the_docs_state(raw_dir):
    """docs/security.md and blenav.limits state the ILC 2.0 sample's archives expand 5.1-5.6 times and its largest
    member is 4.1 MB, far inside the defaults (200 x + 64 MiB, 256 MiB a member): measured here from the headers."""
    import tarfile

    ratios, largest = [], 0
    for tgz in sorted((raw_dir / "ilc20").glob("*.tar.gz")):
        with tarfile.open(tgz, "r|gz") as tf:
            sizes = [m.size for m in tf if m.isfile()]
        ratios.append(sum(sizes) / tgz.stat().st_size)
        largest = max(largest, *sizes)
    assert len(ratios) == 3 and 5.05 <= min(ratios) and max(ratios) < 5.65, ratios
    assert round(largest / 1e6, 1) == 4.1 and largest < limits.DEFAULT_MAX_MEMBER_MB * limits.MIB
    assert max(ratios) < limits.DEFAULT_MAX_ARCHIVE_RATIO
