"""``blenav COMMAND``: one command over every tool, one dialect over both parsers (issue 33, section 2)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from blenav.cli.args import ArgumentParser
from blenav.cli.common import _HYDRA_OPTS, called_as
from blenav.cli.hydra_help import flags_to_overrides
from blenav.cli.main import ALIASES, COMMANDS, main


def blenav(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "blenav", *args], capture_output=True, text=True, timeout=timeout)


def test_listing_names_every_command_and_alias(capsys):
    assert main([]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: blenav COMMAND")
    for name in COMMANDS:
        assert f"\n  {name} " in out
    # every console script of pyproject.toml is an alias of a command
    import tomllib

    from helpers import REPO

    scripts = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["blenav"] == "blenav.cli.main:main"
    for script, target in scripts.items():
        if script != "blenav":
            assert target == f"blenav.cli.{COMMANDS[ALIASES[script]].module}:main", script


def test_unknown_command_is_one_line_with_the_nearest():
    r = blenav("evl", "data=x")
    assert r.returncode == 1 and r.stdout == ""
    assert r.stderr == "blenav: error: unknown command 'evl'; did you mean eval? (blenav --help lists them)\n"


def test_hydra_help_is_usage_experiments_and_settings_not_a_dump():
    r = blenav("eval", "experiment=realwalks", "--help")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("usage: blenav eval ") and "powered by Hydra" not in r.stdout
    assert len(lines) < 70 and max(map(len, lines)) <= 130
    assert "experiments (experiment=NAME):" in r.stdout and "mapnoise_000" in r.stdout
    assert "settings (with experiment=realwalks):" in r.stdout
    methods = next(i for i, l in enumerate(lines) if l.startswith("  methods ("))
    assert "fused_offline" in " ".join(lines[methods:methods + 6])  # the experiment's own methods, not the default's
    assert "  runs=" in r.stdout and "  out=" in r.stdout and "  progress=true" in r.stdout
    r = blenav("sim", "-h")
    assert r.returncode == 0 and r.stdout.startswith("usage: blenav sim ") and "sim: " in r.stdout


def test_flags_become_overrides_and_hydra_options_stay():
    f = lambda *a: flags_to_overrides(list(a), _HYDRA_OPTS)  # noqa: E731
    assert f("--data", "/d", "--out=/o", "--no-progress", "runs=2") == ["data=/d", "out=/o", "progress=false", "runs=2"]
    assert f("--sessions", "a,b", "--overwrite") == ["sessions=a,b", "overwrite=true"]
    assert f("--model-path", "m.onnx") == ["model_path=m.onnx"]
    assert f("--overwrite", "runs=1") == ["overwrite=true", "runs=1"]  # a switch before an override
    assert f("-m", "--cfg", "job", "--config-dir", "/c", "--info", "x=1") == ["-m", "--cfg", "job", "--config-dir",
                                                                               "/c", "--info", "x=1"]
    assert f("--experiment", "x", "--help") == ["experiment=x", "--help"]  # not Hydra's --experimental-rerun
    assert f("--seed", "-1", "--init-s", "-0.5", "--out", "a=b") == ["seed=-1", "init_s=-0.5", "out=true", "a=b"]
    assert f("--out=a=b") == ["out=a=b"]
    assert f("--config-d", "/c", "--hydra-h") == ["--config-d", "/c", "--hydra-h"]  # abbreviations of Hydra's own
    assert f("a=1", "--", "--b") == ["a=1", "--b"]


def test_data_flag_reaches_the_dataset_check():
    """``--data DIR`` is ``data=DIR`` (it used to be Hydra's usage and exit 2); an unknown flag is the unknown key."""
    r = blenav("eval", "--data", "/nonexistent/ds", "runs=1", "out=/tmp/never_written")
    assert r.returncode == 1 and r.stderr.count("\n") == 1
    assert r.stderr.startswith("blenav eval: error: ") and "/nonexistent/ds" in r.stderr
    r = blenav("eval", "--dta", "/x")
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "did you mean 'data'" in r.stderr


def parser() -> ArgumentParser:
    p = ArgumentParser("blenav-x")
    p.add_argument("dataset")
    p.add_argument("--out")
    p.add_argument("--sessions")
    p.add_argument("--keep", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    return p


def test_argparse_commands_read_key_values():
    a = parser().parse_args(["out=/o", "data=/d", "sessions=a,b", "progress=false", "keep=true"])
    assert (a.dataset, a.out, a.sessions, a.no_progress, a.keep) == ("/d", "/o", "a,b", True, True)
    a = parser().parse_args(["/d", "--out", "/o", "keep=false", "progress=true"])
    assert (a.dataset, a.out, a.keep, a.no_progress) == ("/d", "/o", False, False)
    a = parser().parse_args(["/path/with=sign"])  # a word whose key names no option stays a positional
    assert a.dataset == "/path/with=sign"
    with pytest.raises(ValueError, match="keep=maybe: expected true or false"):
        parser().parse_args(["/d", "keep=maybe"])


def test_argparse_wrong_flag_is_one_line_exit_1(capsys):
    with called_as("blenav x"), pytest.raises(SystemExit) as e:
        parser().parse_args(["/d", "--bogus"])
    assert e.value.code == 1
    err = capsys.readouterr().err
    assert err == "blenav x: error: unrecognized arguments: --bogus (see blenav x --help)\n"
    r = blenav("map", "/d", "--out", "/o", "--bogus")
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and r.stderr.startswith("blenav map: error: ")


def test_plot_sessions_accept_commas_and_spaces(tmp_path):
    from helpers import make_tiny_dataset

    ds = make_tiny_dataset(tmp_path / "d")
    ids = sorted(p.name for p in (ds / "sessions").iterdir())
    r = blenav("plot", f"data={ds}", f"sessions={ids[0]},nope", f"out={tmp_path / 'p'}")
    assert r.returncode == 1 and f"no session(s) nope in {ds}" in r.stderr
