#!/usr/bin/env python3
"""Regression snapshot: small, seeded runs of the project's experiments, digested so that a refactor can be
shown to leave every number bit-identical (issue 27).

    python tools/regression_snapshot.py run   --work DIR --out SNAP.json [--only NAME,...] [--ilc-raw DIR]
    python tools/regression_snapshot.py check --work DIR --ref SNAP.json [--only NAME,...] [--ilc-raw DIR]
    make regression-check     # check against the reference the Makefile names (tests/regression/) in data/regression

What it covers (5 min on a shared 2-core machine). Inputs, built in DIR with fixed seeds and non-default
building names: simulated datasets (``blenav-sim``: an office, a one-walk office, a CRF hall, a small
four-phone survey, eight procedural buildings, a small two-phone lab), a map prior trained one short epoch
(``train.py experiment=mapprior``) and exported (``export.py``), and the first ILC_WALKS walks (by file name)
of ILC 2.0 site1/F2 (``blenav-import ilc20`` on a folder holding only those walks; skipped with the reason
when the raw archive is absent) with a beacon map from ``blenav-map`` on realwalks' train walks.
Experiments (``blenav-eval``, shrunk: 1-2 runs, 60-120 s walks, 50 optimizer steps for networks): mapfusion_002,
frontend_000, backend_000, mapnoise_000, crf_004_table1, crf_004_fig12, crossphone_003, mapprior_003_table36,
mapprior_003_table37, leaderboard, realwalks, realwalks_mapped (realwalks with the learned beacon map: the
range-based rows). ``--only`` picks some (their inputs are built as needed).

Digest. Each results.json is made canonical: the keys in VOLATILE (timings, real-time factors, peak memory:
the only fields that differed between two runs of the same code) are dropped at every depth, DIR and the
repository root in strings become ``<WORK>`` / ``<REPO>``, dicts are sorted by key (the method order is kept
as a list), floats are written with repr (exact), and the result is hashed (sha256) as a whole and per
section (each top-level key, each method). Every input dataset is hashed
too (file bytes, paths normalised in text files), so a difference can be traced to the simulator or
importer. The snapshot also keeps per method the key numbers (KEY_NUMBERS: rmse / error means ...) to show
a difference readably, the command of each experiment and its wall time (not compared). DIR/canonical/NAME.json
holds the canonical form of the last run; diff two of them for every field.

Determinism: subprocesses run with one BLAS / OpenMP thread (OMP_NUM_THREADS etc.; the configs already
set torch threads=1 and Lightning deterministic); two runs of b6170be in different DIRs gave the same
digests (and of 302d488 / 733921b, the reference since issue 30). Bit-identity holds on one machine and library
stack: a reference made elsewhere (another CPU,
numpy / torch / onnxruntime build) may differ in the last bits without any code change.

Refresh the reference (after a change that is meant to alter results, or on a new machine): check out the
reference commit in a worktree (``git worktree add /tmp/ref COMMIT``), copy this script into it, run
``PYTHONPATH=/tmp/ref/src .venv/bin/python /tmp/ref/tools/regression_snapshot.py run --work /tmp/snap
--out tests/regression/snapshot_<commit>.json`` twice (the digests must agree; the second into another
--work), commit the file and point the Makefile's regression-check at it.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent
MARKER = ".regression_snapshot"  # DIR is wiped only when it holds this file (or is empty)

# dropped at every depth before hashing: they measure the machine, not the method (found by diffing two runs)
VOLATILE = {"wall_s", "realtime_factor", "train_s", "predict_s", "fit_s", "peak_memory_mb", "peak_rss_mb"}
# per method, the numbers shown when a digest differs (dotted paths inside results.json methods.<label>)
KEY_NUMBERS = ("rmse_m.mean", "error_m.mean", "error_m.median", "error_m.p90", "ate_m", "ee_m")
THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
              "NUMEXPR_NUM_THREADS": "1"}

ILC_FLOOR = "site1/F2"
ILC_ARCHIVE = "site1_F2.tar.gz"
ILC_WALKS = 8
ILC_DEFAULT_RAW = REPO.parent / "shared" / "data" / "raw" / "ilc20"

# Roy's odometry errors of the map-prior tables (Makefile MP_SIM)
MP_ODOMETRY = ["sim.odometry.drift_deg_per_min_std=6", "sim.odometry.heading_rw_deg=0.8",
               "sim.odometry.scale_std=0.1"]
MP_TEST = "[s006_pixel-4xl_pedestrian,s007_pixel-3xl_pedestrian]"  # the held-out buildings 006 and 007
SIMS = {  # input name -> blenav-sim overrides (out= added)
    "office": ["sim=office_45x55", "sim.name=snap_office", "seed=1", "duration_s=120", "sessions=3",
               "sim.carriers=[pedestrian,robot,pedestrian]"],
    "backend": ["sim=office_45x55", "sim.name=snap_backend", "seed=0", "duration_s=90", "sessions=1"],
    "crf": ["sim=crf_004", "sim.name=snap_hall", "seed=1", "duration_s=120", "sessions=4"],
    "survey": ["sim=small", "sim.name=snap_survey", "seed=3", "duration_s=60", "sessions=8",
               "sim.receivers=[iphone-7,galaxy-s10,mi-9,pixel-3xl]", "sim.carriers=[pedestrian]",
               "sim.unlabelled_every=0"],
    "proc": ["sim=procedural", "sim.name=snap_proc", "seed=4", "duration_s=90", "sessions=8",
             "sim.carriers=[pedestrian]", "sim.unlabelled_every=0", *MP_ODOMETRY],
    "wharf": ["sim=small", "sim.name=snap_wharf", "sim.receivers=[honor-20-pro,redmi-note8]",
              "sim.carriers=[pedestrian,robot]", "seed=2", "duration_s=90", "sessions=4"],
}
SMALL_NET = "trainer.budget.max_steps=50"

# name -> (inputs it needs, blenav-eval overrides; {data}, {mapprior} are filled with paths)
EXPERIMENTS = {
    "mapfusion_002": (["office"], ["data={office}", "runs=2", "calibration=[s000_iphone-7_pedestrian]"]),
    "frontend_000": (["office"], ["data={office}", "runs=2", "calibration=[s000_iphone-7_pedestrian]"]),
    "backend_000": (["backend"], ["data={backend}", "runs=2"]),
    "mapnoise_000": (["backend"], ["data={backend}", "runs=2"]),
    "crf_004_table1": (["crf"], ["data={crf}"]),
    "crf_004_fig12": (["crf"], ["data={crf}"]),
    "crossphone_003": (["survey"], ["data={survey}", "data.train_devices=[iphone-7,galaxy-s10]",
                                    "data.known_devices=[iphone-7]", "data.unlabelled_devices=[mi-9]",
                                    SMALL_NET, "experiment.learned.semi.semi.steps=20"]),
    "mapprior_003_table36": (["proc", "mapprior"], ["data={proc}", f"sessions={MP_TEST}", "runs=2",
                                                    "model_path={mapprior}"]),
    "mapprior_003_table37": (["proc", "mapprior"], ["data={proc}", f"sessions={MP_TEST}", "runs=2",
                                                    "model_path={mapprior}"]),
    "leaderboard": (["wharf", "mapprior"], ["data={wharf}", "runs=1", "model_path={mapprior}",
                                            "+split={train_fraction: 0.5, seed: 0}",
                                            "methods.locnet_ble." + SMALL_NET]),
    "realwalks": (["ilc", "mapprior"], ["data={ilc}", "runs=1", "model_path={mapprior}",
                                        "methods.locnet_wifi." + SMALL_NET, "methods.transnet_wifi." + SMALL_NET,
                                        "methods.net_both." + SMALL_NET]),
    "realwalks_mapped": (["ilc_mapped", "mapprior"], ["experiment=realwalks", "data={ilc_mapped}", "runs=1",
                                                      "model_path={mapprior}", "methods.locnet_wifi." + SMALL_NET,
                                                      "methods.transnet_wifi." + SMALL_NET,
                                                      "methods.net_both." + SMALL_NET]),
}


class Skip(Exception):
    """An input that cannot be built here (e.g. the ILC archive is absent): its experiments are skipped."""


class Runner:
    """Builds the inputs in `work` (each once per run) and runs the experiments; records commands and times."""

    def __init__(self, work: Path, ilc_raw: Path):
        self.work, self.ilc_raw = work, ilc_raw
        self.built: dict[str, Path] = {}
        self.skipped: dict[str, str] = {}
        self.failed: dict[str, str] = {}  # inputs whose build failed: not retried
        self.input_digests: dict[str, str] = {}
        self.env = {**os.environ, **THREAD_ENV}

    def sh(self, name: str, cmd: list[str]) -> float:
        """Run one command from the repository root, output in WORK/logs/NAME.log; seconds it took."""
        log = self.work / "logs" / f"{name}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        with open(log, "a") as f:
            f.write("$ " + " ".join(cmd) + "\n")
            f.flush()
            rc = subprocess.run(cmd, cwd=REPO, env=self.env, stdout=f, stderr=subprocess.STDOUT).returncode
        if rc != 0:
            tail = [x for x in log.read_text().splitlines() if x.strip()][-15:]
            raise RuntimeError(f"{name}: exit {rc}: {tail[-1] if tail else '(no output)'}\n  command: {' '.join(cmd)}"
                               f"\n  " + "\n  ".join(tail) + f"\n  (log: {log})")
        return time.perf_counter() - t0

    def need(self, name: str) -> Path:
        if name in self.skipped:
            raise Skip(self.skipped[name])
        if name in self.failed:
            raise RuntimeError(f"input {name} failed earlier: {self.failed[name]}")
        if name not in self.built:
            t0 = time.perf_counter()
            try:
                builder = getattr(self, "_build_" + name, None)
                self.built[name] = builder() if builder else self._sim(name)
            except Skip as e:
                self.skipped[name] = str(e)
                print(f"  input {name}: SKIPPED ({e})", flush=True)
                raise
            except RuntimeError as e:
                self.failed[name] = str(e).splitlines()[0]
                raise
            if (self.built[name] / "dataset.yaml").exists() or name == "mapprior":
                self.input_digests[name] = tree_digest(self.built[name], self.subs())
            print(f"  input {name}: built in {time.perf_counter() - t0:.1f} s", flush=True)
        return self.built[name]

    def subs(self) -> list[tuple[str, str]]:
        return [(str(self.work), "<WORK>"), (str(REPO), "<REPO>")]

    def _sim(self, name: str) -> Path:
        out = self.work / "data" / name
        self.sh("input_" + name, [str(BIN / "blenav-sim"), *SIMS[name], f"out={out}", "progress=false",
                                  "overwrite=true"])
        return out

    def _build_mapprior(self) -> Path:
        """A map prior trained one short epoch on the procedural buildings but 006/007, exported (train.py,
        export.py): the learned-map rows of the map-prior tables, the leaderboard and realwalks use it."""
        proc = self.need("proc")
        run, onnx = self.work / "runs" / "mapprior", self.work / "runs" / "mapprior_onnx"
        shutil.rmtree(run, ignore_errors=True)
        shutil.rmtree(onnx, ignore_errors=True)
        self.sh("input_mapprior", [sys.executable, str(REPO / "train.py"), "experiment=mapprior", f"data={proc}",
                                   f"out={run}", "data.val_buildings=[snap_proc_006,snap_proc_007]",
                                   "trainer.max_epochs=1", "data.samples_per_epoch=128", "data.val_samples=64",
                                   "plots=false", "trainer.enable_progress_bar=false"])
        self.sh("input_mapprior", [sys.executable, str(REPO / "export.py"), f"ckpt={run / 'last.ckpt'}",
                                   f"out={onnx}"])
        return onnx

    def _build_ilc(self) -> Path:
        """The first ILC_WALKS walks (sorted by file name) of one floor, copied out of the raw archive into a
        floor folder (only the plan files and those walks), then ``blenav-import ilc20`` on it."""
        archive = self.ilc_raw / ILC_ARCHIVE
        if not archive.is_file():
            raise Skip(f"no ILC 2.0 archive at {archive} (--ilc-raw DIR)")
        raw = self.work / "data" / "ilc_raw"
        floor = raw / ILC_FLOOR
        walk = re.compile(re.escape(ILC_FLOOR) + r"/path_data_files/([0-9a-f]{24})\.txt")
        plan = {f"{ILC_FLOOR}/floor_info.json", f"{ILC_FLOOR}/geojson_map.json"}
        with tarfile.open(archive, "r:gz") as tar:
            members = [m for m in tar.getmembers() if m.isfile()]
            walks = sorted((m for m in members if walk.fullmatch(m.name)), key=lambda m: m.name)[:ILC_WALKS]
            for m in [m for m in members if m.name in plan] + walks:  # names checked above: no path escapes
                dest = raw / m.name
                dest.parent.mkdir(parents=True, exist_ok=True)
                dest.write_bytes(tar.extractfile(m).read())
        out = self.work / "data" / "ilc"
        self.sh("input_ilc", [str(BIN / "blenav-import"), "ilc20", str(floor), str(out)])
        return out

    def _build_ilc_mapped(self) -> Path:
        """The ILC walks with beacon positions from ``blenav-map`` on realwalks' train walks (as
        ``make realwalks-tables``: the full import with the mapped anchors.csv, unplaced beacons kept)."""
        ilc = self.need("ilc")
        res = self.work / "results" / "realwalks" / "results.json"
        if not res.exists():
            self.experiment("realwalks")
        train = json.loads(res.read_text())["split"]["train"]
        mapped, out = self.work / "data" / "ilc_mapped_only", self.work / "data" / "ilc_mapped"
        shutil.rmtree(mapped, ignore_errors=True)
        shutil.rmtree(out, ignore_errors=True)
        self.sh("input_ilc_mapped", [str(BIN / "blenav-map"), str(ilc), "--out", str(mapped), "--keep-unplaced",
                                     "--sessions", ",".join(train)])
        shutil.copytree(ilc, out)
        for b in (mapped / "buildings").iterdir():
            shutil.copy(b / "anchors.csv", out / "buildings" / b.name / "anchors.csv")
        return out

    def experiment(self, name: str) -> dict:
        """Run one experiment; its canonical results, digests, key numbers and command."""
        needs, overrides = EXPERIMENTS[name]
        paths = {n: str(self.need(n)) for n in needs}
        out = self.work / "results" / name
        shutil.rmtree(out, ignore_errors=True)  # crossphone reuses finished training runs in OUT/runs
        args = []
        for o in overrides:
            for n, p in paths.items():
                o = o.replace("{" + n + "}", p)
            args.append(o)
        if not any(a.startswith("experiment=") for a in args):
            args.insert(0, f"experiment={name}")
        args += [f"out={out}", "progress=false", "plots=false"]
        wall = self.sh(name, [str(BIN / "blenav-eval"), *args])
        canon = canonical(json.loads((out / "results.json").read_text()), self.subs())
        (self.work / "canonical").mkdir(exist_ok=True)
        (self.work / "canonical" / f"{name}.json").write_text(dumps(canon, indent=1) + "\n")
        return {"command": normalise(" ".join(["blenav-eval", *args]), self.subs()),
                "digest": sha(dumps(canon)),
                "sections": {k: sha(dumps(v)) for k, v in sections(canon).items()},
                "numbers": key_numbers(canon),
                "wall_s": round(wall, 1)}


def normalise(s: str, subs) -> str:
    for a, b in subs:
        s = s.replace(a, b)
    return s


def canonical(obj, subs):
    """results.json without VOLATILE keys (at any depth), DIR and the repository root in strings normalised."""
    if isinstance(obj, dict):
        return {k: canonical(v, subs) for k, v in obj.items() if k not in VOLATILE}
    if isinstance(obj, list):
        return [canonical(v, subs) for v in obj]
    if isinstance(obj, str):
        return normalise(obj, subs)
    return obj


def dumps(obj, indent=None) -> str:
    # json writes floats with float.__repr__ (the shortest string that reads back to the same double)
    return json.dumps(obj, sort_keys=True, indent=indent, allow_nan=True, separators=None if indent else (",", ":"))


def sha(s: str) -> str:
    return hashlib.sha256(s.encode()).hexdigest()


def sections(canon: dict) -> dict:
    """Top-level keys, the methods' order, and each method on its own."""
    out = {k: v for k, v in canon.items() if k != "methods"}
    methods = canon.get("methods") or {}
    out["methods:order"] = list(methods)
    out.update({f"methods/{m}": v for m, v in methods.items()})
    return out


def key_numbers(canon: dict) -> dict:
    out = {}
    for m, res in (canon.get("methods") or {}).items():
        nums = {}
        for path in KEY_NUMBERS:
            v = res
            for part in path.split("."):
                v = v.get(part) if isinstance(v, dict) else None
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                nums[path] = v
        out[m] = nums
    return out


def tree_digest(root: Path, subs) -> str:
    """sha256 over the files below root (relative path + bytes; text files with paths normalised)."""
    h = hashlib.sha256()
    for p in sorted(x for x in root.rglob("*") if x.is_file()):
        data = p.read_bytes()
        if p.suffix in {".yaml", ".json", ".csv", ".geojson", ".txt", ".md"}:
            data = normalise(data.decode("utf-8", "replace"), subs).encode()
        h.update(str(p.relative_to(root)).encode() + b"\0" + hashlib.sha256(data).digest())
    return h.hexdigest()


def prepare(work: Path) -> None:
    if work.exists() and any(work.iterdir()) and not (work / MARKER).exists():
        sys.exit(f"regression_snapshot: error: {work} is not empty and was not made by this script "
                 f"(no {MARKER}); give an empty or new --work")
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    (work / MARKER).write_text("made by tools/regression_snapshot.py; wiped by its next run\n")


def run_all(work: Path, ilc_raw: Path, only: list[str] | None) -> dict:
    prepare(work)
    r = Runner(work.resolve(), ilc_raw)
    names = only or list(EXPERIMENTS)
    snap = {"format": 1, "tool": "tools/regression_snapshot.py", "code": code_version(),
            "env": {"python": sys.version.split()[0], **THREAD_ENV}, "experiments": {}, "skipped": {}, "failed": {}}
    t_all = time.perf_counter()
    for i, name in enumerate(names, 1):
        print(f"[{i}/{len(names)}] {name}", flush=True)
        t0 = time.perf_counter()
        try:
            snap["experiments"][name] = res = r.experiment(name)
        except Skip as e:
            snap["skipped"][name] = str(e)
            print(f"[{i}/{len(names)}] {name}: SKIPPED ({e})", flush=True)
            continue
        except RuntimeError as e:  # a command failed: reported, the other experiments still run
            snap["failed"][name] = str(e)
            print(f"[{i}/{len(names)}] {name}: FAILED after {time.perf_counter() - t0:.1f} s\n  {e}", flush=True)
            continue
        print(f"[{i}/{len(names)}] {name}: {time.perf_counter() - t0:.1f} s (eval {res['wall_s']} s) "
              f"digest {res['digest'][:12]}", flush=True)
    snap["inputs"] = dict(sorted(r.input_digests.items()))
    snap["wall_s"] = round(time.perf_counter() - t_all, 1)
    print(f"total {snap['wall_s']} s", flush=True)
    return snap


def code_version() -> dict:
    def git(*a):
        p = subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True)
        return p.stdout.strip() if p.returncode == 0 else None
    status = git("status", "--porcelain", "--untracked-files=no", "--", "src", "conf", "train.py", "export.py")
    return {"commit": git("rev-parse", "--short", "HEAD"), "src_dirty": bool(status)}


def compare(ref: dict, cur: dict) -> list[str]:
    """Lines describing how `cur` differs from `ref` for one experiment ([] when identical)."""
    if ref["digest"] == cur["digest"]:
        return []
    lines = []
    rs, cs = ref["sections"], cur["sections"]
    for sec in list(rs) + [s for s in cs if s not in rs]:
        if rs.get(sec) == cs.get(sec):
            continue
        if sec not in cs or sec not in rs:
            lines.append(f"    {sec}: {'missing now' if sec not in cs else 'new (not in the reference)'}")
            continue
        shown = False
        if sec.startswith("methods/"):
            m = sec[len("methods/"):]
            a, b = ref["numbers"].get(m, {}), cur["numbers"].get(m, {})
            for k in sorted(set(a) | set(b)):
                if a.get(k) != b.get(k):
                    lines.append(f"    {m}: {k} {a.get(k)!r} -> {b.get(k)!r}")
                    shown = True
        if not shown:
            lines.append(f"    {sec}: differs" + (" (not in its key numbers)" if sec.startswith("methods/") else ""))
    return lines


def check(work: Path, ref_path: Path, ilc_raw: Path, only: list[str] | None) -> int:
    ref = json.loads(ref_path.read_text())
    names = only or [n for n in EXPERIMENTS if n in ref["experiments"] or n in ref.get("skipped", {})]
    cur = run_all(work, ilc_raw, names)
    (work / "snapshot_current.json").write_text(dumps(cur, indent=1) + "\n")
    bad = 0
    print(f"\nreference {ref_path} (code {ref['code']}) vs now (code {cur['code']}):")
    for name in names:
        if name in cur["skipped"]:
            print(f"  {name:22s} SKIPPED here: {cur['skipped'][name]}")
            continue
        if name in cur["failed"]:
            bad += 1
            print(f"  {name:22s} FAILED: {cur['failed'][name].splitlines()[0]}")
            continue
        if name not in ref["experiments"]:
            print(f"  {name:22s} NOT IN REFERENCE ({ref.get('skipped', {}).get(name, 'not run')})")
            continue
        diff = compare(ref["experiments"][name], cur["experiments"][name])
        bad += bool(diff)
        print(f"  {name:22s} {'DIFFERENT' if diff else 'IDENTICAL'}")
        for line in diff:
            print(line)
        if diff:
            print(f"    every field now: {work / 'canonical' / (name + '.json')} (diff it with a reference run's)")
    for name, d in cur["inputs"].items():
        r = ref.get("inputs", {}).get(name)
        if r is not None and r != d:
            bad += 1
            print(f"  input {name:16s} DIFFERENT (files of {work / 'data' / name} or runs/{name})")
    print(f"{'DIFFERENT' if bad else 'IDENTICAL'}: {bad} difference(s); current snapshot: "
          f"{work / 'snapshot_current.json'}")
    return 1 if bad else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="regression_snapshot", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    for c in ("run", "check"):
        p = sub.add_parser(c)
        p.add_argument("--work", type=Path, required=True, help="scratch folder (wiped; created)")
        p.add_argument("--only", help=f"comma-separated experiments (default all: {','.join(EXPERIMENTS)})")
        p.add_argument("--ilc-raw", type=Path, default=ILC_DEFAULT_RAW,
                       help=f"folder with {ILC_ARCHIVE} (default {ILC_DEFAULT_RAW})")
        if c == "run":
            p.add_argument("--out", type=Path, required=True, help="snapshot JSON to write")
        else:
            p.add_argument("--ref", type=Path, required=True, help="reference snapshot JSON")
    a = ap.parse_args(argv)
    only = a.only.split(",") if a.only else None
    unknown = [n for n in only or [] if n not in EXPERIMENTS]
    if unknown:
        ap.error(f"unknown experiment(s) {unknown}; known: {', '.join(EXPERIMENTS)}")
    if a.cmd == "run":
        snap = run_all(a.work, a.ilc_raw, only)
        if snap["failed"]:
            print(f"regression_snapshot: error: {len(snap['failed'])} experiment(s) failed "
                  f"({', '.join(snap['failed'])}); no snapshot written", file=sys.stderr)
            return 1
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(dumps(snap, indent=1) + "\n")
        print(f"wrote {a.out}")
        return 0
    return check(a.work, a.ref, a.ilc_raw, only)


if __name__ == "__main__":
    sys.exit(main())
