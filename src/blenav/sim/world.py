"""The world simulator: buildings, anchors and sessions written as a format-v1 dataset.

Every random draw comes from one ``numpy.random.SeedSequence(seed)``: the building's anchors, maps and
fields from a child keyed by the building, each session from a child keyed by its index, so the same
seed gives the same bytes and adding sessions does not change earlier ones.
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.ndimage import distance_transform_edt
from shapely.geometry import box

from blenav.data.floor import OCCUPIED
from blenav.data.writer import write_building, write_dataset_meta, write_session

from .config import SimConfig
from .inertial import DisturbanceField, simulate_imu, simulate_mag, simulate_odometry
from .layout import Layout, LayoutConfig, generate_layout
from .motion import Trajectory, survey, walk
from .radio import AnchorMaps, rtt_wifi_rssi, simulate_ble, simulate_rtt
from .calibration import profile_for

#: spawn-key suffix of the per-session random stream of the WiFi RSSI in rtt.csv (radio.rtt_wifi_rssi)
RTT_RSSI_STREAM = 0x525353

log = logging.getLogger("blenav.sim")


@dataclass
class World:
    """One simulated building with true anchors and the fields its sessions share."""

    id: str
    layout: Layout
    ble_xyz: np.ndarray  # (B, 3) true positions, m
    ble_p1m: np.ndarray  # (B,) true RSSI at 1 m, dBm
    ap_xyz: np.ndarray  # (P, 3)
    ap_offset: np.ndarray  # (P,) RTT offset, m
    ble_maps: AnchorMaps
    ap_maps: AnchorMaps
    mag_field: DisturbanceField
    landmarks: np.ndarray  # (L, 2)


def farthest_points(rng: np.random.Generator, cand: np.ndarray, k: int) -> np.ndarray:
    """Greedy farthest-point sample of k rows of cand (N, 2), starting at a random row."""
    if len(cand) == 0:
        raise ValueError("no candidate positions for anchors: the floor has no free space")
    chosen = [int(rng.integers(len(cand)))]
    d = np.linalg.norm(cand - cand[chosen[0]], axis=1)
    for _ in range(min(k, len(cand)) - 1):
        chosen.append(int(np.argmax(d)))
        d = np.minimum(d, np.linalg.norm(cand - cand[chosen[-1]], axis=1))
    return cand[chosen]


def _wall_candidates(layout: Layout, near_m: float = 0.4) -> np.ndarray:
    """Free pixel centres within near_m of an obstacle (wall-mounted beacons), subsampled to 0.5 m."""
    free = layout.occupancy != OCCUPIED
    dist = distance_transform_edt(free) * layout.resolution
    step = max(1, int(0.5 / layout.resolution))
    mask = np.zeros_like(free)
    mask[::step, ::step] = True
    r, c = np.nonzero(mask & (dist > 0.1) & (dist <= near_m))
    h = layout.occupancy.shape[0]
    return np.stack([(c + 0.5) * layout.resolution, (h - 1 - r + 0.5) * layout.resolution], axis=1)


def build_world(cfg: SimConfig, k: int, ss: np.random.SeedSequence) -> World:
    lc = LayoutConfig(**{**asdict(cfg.layout), "layout_seed": cfg.layout.layout_seed + k})
    layout = generate_layout(lc)
    rng = np.random.default_rng(ss)
    ble_xy = farthest_points(rng, _wall_candidates(layout), cfg.n_beacons)
    ble_xyz = np.column_stack([ble_xy, np.full(len(ble_xy), cfg.beacon_height_m)])
    p1m = cfg.ble.tx_power_dbm + cfg.ble.tx_spread_db * rng.standard_normal(len(ble_xy))
    free_pts = _wall_candidates(layout, near_m=3.0)
    ap_xy = farthest_points(rng, free_pts, cfg.n_rtt_aps) if cfg.n_rtt_aps else np.zeros((0, 2))
    ap_xyz = np.column_stack([ap_xy, np.full(len(ap_xy), cfg.ap_height_m)])
    ap_offset = cfg.rtt.offset_mean_m + cfg.rtt.offset_std_m * rng.standard_normal(len(ap_xy))
    maps = AnchorMaps(layout.occupancy, layout.resolution, layout.origin, ble_xy, cfg.ble.grid_m, cfg.ble.max_range_m,
                      rng, cfg.ble.shadow_corr_m)
    ap_maps = AnchorMaps(layout.occupancy, layout.resolution, layout.origin, ap_xy, cfg.ble.grid_m, cfg.rtt.max_range_m)
    field = DisturbanceField(rng, cfg.mag, layout.width_m, layout.height_m)
    junctions = layout.nodes[layout.junctions] if layout.junctions else layout.nodes
    n_l = min(cfg.visual.n_landmarks, len(junctions))
    landmarks = junctions[rng.permutation(len(junctions))[:n_l]]
    name = cfg.name if cfg.buildings == 1 else f"{cfg.name}_{k:03d}"
    return World(name, layout, ble_xyz, p1m, ap_xyz, ap_offset, maps, ap_maps, field, landmarks)


def write_world(root: Path, cfg: SimConfig, w: World, rng: np.random.Generator) -> None:
    """Building folder: floor image, anchors (perturbed prior + true columns), rooms, navigation graph."""
    def anchors(kind, prefix, xyz, p1m, model):
        prior = xyz[:, :2] + cfg.prior_map_std_m * rng.standard_normal((len(xyz), 2))
        return pd.DataFrame({
            "anchor_id": [f"{prefix}{i:03d}" for i in range(len(xyz))], "kind": kind,
            "x": prior[:, 0], "y": prior[:, 1], "z": xyz[:, 2], "floor": 0,
            "tx_power_dbm": cfg.ble.tx_power_dbm if kind == "ble" else np.nan, "channel_model": model,
            "x_true": xyz[:, 0], "y_true": xyz[:, 1], "z_true": xyz[:, 2],
            "tx_power_dbm_true": p1m if p1m is not None else np.nan})

    b = cfg.ble
    a = pd.concat([
        anchors("ble", "ble-", w.ble_xyz, w.ble_p1m,
                f"blenav-sim: log-distance n={b.path_loss_exponent} walls {b.wall_db} dB shadowing {b.shadow_std_db} dB"),
        anchors("wifi_rtt", "ap-", w.ap_xyz, None, "blenav-sim: RTT with per-AP offset and NLOS bias")],
        ignore_index=True)
    L = w.layout
    rooms = [{"id": r.id, "floor": 0, "geometry": box(*r.rect)} for r in L.rooms]
    nav = [{"id": f"e{k:04d}", "floor": 0, "geometry": g} for k, g in enumerate(L.edge_lines())]
    write_building(root, w.id, f"{cfg.name} (simulated)", [{"id": 0, "occupancy": L.occupancy,
                   "resolution": L.resolution, "origin": L.origin, "z": 0.0}], a, rooms, nav,
                   landmarks=[[float(x), float(y)] for x, y in w.landmarks])


def _quat_wxyz(traj: Trajectory, idx: np.ndarray) -> np.ndarray:
    q = traj.rot[idx].as_quat()  # scipy: x, y, z, w
    return np.column_stack([q[:, 3], q[:, :3]])


def visual_fixes(rng, cfg: SimConfig, w: World, t: np.ndarray, xyz: np.ndarray, yaw: np.ndarray) -> pd.DataFrame:
    """A fix each time the device comes within radius_m of a landmark (at most one per min_interval_s)."""
    rows = []
    v = cfg.visual
    for lm in w.landmarks:
        inside = np.linalg.norm(xyz[:, :2] - lm, axis=1) < v.radius_m
        entries = np.flatnonzero(inside[1:] & ~inside[:-1]) + 1
        last = -np.inf
        for e in entries:
            if t[e] - last >= v.min_interval_s:
                rows.append(e)
                last = t[e]
    rows = np.array(sorted(rows), dtype=int)
    n = len(rows)
    return pd.DataFrame({
        "t": t[rows], "x": xyz[rows, 0] + v.pos_std_m * rng.standard_normal(n),
        "y": xyz[rows, 1] + v.pos_std_m * rng.standard_normal(n), "z": xyz[rows, 2],
        "yaw": np.angle(np.exp(1j * (yaw[rows] + np.radians(v.yaw_std_deg) * rng.standard_normal(n))))})


def simulate_session(cfg: SimConfig, w: World, i: int, duration_s: float, ss: np.random.SeedSequence):
    """Meta and streams of session ``i`` in world ``w``."""
    rng = np.random.default_rng(ss)
    profile = profile_for(cfg.receivers[i % len(cfg.receivers)], cfg.ble)
    carrier = cfg.carriers[i % len(cfg.carriers)]
    labelled = not (cfg.unlabelled_every and (i + 1) % cfg.unlabelled_every == 0)
    if carrier == "static":
        traj = survey(w.layout, rng, cfg.motion, duration_s)
    else:
        traj = walk(w.layout, rng, cfg.motion, duration_s, carrier)
    imu = simulate_imu(rng, cfg.imu, traj, hand=carrier == "pedestrian")
    t_mag, mag = simulate_mag(rng, cfg.mag, traj, w.mag_field)
    body = cfg.ble.body_db if carrier == "pedestrian" else 0.0
    tb, ab, rb = simulate_ble(rng, cfg.ble, profile, w.ble_maps, w.ble_xyz, w.ble_p1m, traj.t, traj.xyz,
                              traj.heading, body, traj.duration)
    tr, ar, rr, sr = simulate_rtt(rng, cfg.rtt, w.ap_maps, w.ap_xyz, w.ap_offset, traj.t, traj.xyz, traj.duration)
    rtt = pd.DataFrame({"t": tr, "anchor_id": np.char.add("ap-", np.char.zfill(ar.astype(str), 3)),
                        "range_m": rr, "range_std_m": sr})
    if cfg.rtt.write_rssi:  # a stream of its own (RTT_RSSI_STREAM): every other output of the seed is unchanged
        rng_w = np.random.default_rng(np.random.SeedSequence(ss.entropy, spawn_key=ss.spawn_key + (RTT_RSSI_STREAM,)))
        rtt["rssi"] = rtt_wifi_rssi(rng_w, cfg.rtt, w.ap_maps, w.ap_xyz, tr, ar, traj.t, traj.xyz)
    t_odo, odo = simulate_odometry(rng, cfg.odometry, traj)
    step = max(1, int(round(cfg.motion.imu_rate_hz / cfg.groundtruth_rate_hz)))
    gi = np.arange(0, len(traj.t), step)
    fwd = traj.rot[gi].apply([0.0, 1.0, 0.0])
    dev_yaw = np.arctan2(fwd[:, 1], fwd[:, 0])
    streams = {
        "imu": pd.DataFrame({"t": traj.t, "ax": imu[:, 0], "ay": imu[:, 1], "az": imu[:, 2],
                             "gx": imu[:, 3], "gy": imu[:, 4], "gz": imu[:, 5]}),
        "mag": pd.DataFrame({"t": t_mag, "mx": mag[:, 0], "my": mag[:, 1], "mz": mag[:, 2]}),
        "rssi": pd.DataFrame({"t": tb, "anchor_id": np.char.add("ble-", np.char.zfill(ab.astype(str), 3)),
                              "rssi": rb}),
        "rtt": rtt,
        "visual": visual_fixes(rng, cfg, w, traj.t[gi], traj.xyz[gi], dev_yaw),
    }
    if carrier != "static":  # a survey is moved between points off the clock: no odometry
        streams["odometry"] = pd.DataFrame({"t": t_odo, "x": odo[:, 0], "y": odo[:, 1]})
    if labelled:
        q = _quat_wxyz(traj, gi)
        streams["groundtruth"] = pd.DataFrame({"t": traj.t[gi], "x": traj.xyz[gi, 0], "y": traj.xyz[gi, 1],
                                               "z": traj.xyz[gi, 2], "qw": q[:, 0], "qx": q[:, 1], "qy": q[:, 2],
                                               "qz": q[:, 3]})
    meta = {"building": w.id, "floor": 0, "device_model": profile.name, "carrier": carrier, "labelled": labelled,
            "notes": f"blenav-sim {cfg.name}, session {i}", "receiver_brand": profile.brand,
            # a gyroscope with a bias (the default: a raw MEMS gyro) is not calibrated (blenav.filters.yaw_hold)
            "gyro_calibrated": bool(cfg.imu.gyro_bias_std == 0 and cfg.imu.gyro_bias_rw == 0)}
    return meta, streams


def sim_parameters(cfg: SimConfig, seed: int) -> dict:
    """The simulator's resolved settings as plain YAML data (``dataset.yaml`` key ``simulator``: ``preset``,
    ``seed``, ``config`` = :class:`SimConfig` as a dict), so a consumer (the PCRLB of
    :mod:`blenav.eval.pcrlb`) knows the channel and motion models the data came from."""
    import json

    return {"preset": cfg.name, "seed": int(seed), "config": json.loads(json.dumps(asdict(cfg)))}


def simulate(cfg: SimConfig, seed: int, out: str | Path, duration_s: float, sessions: int,
             progress: bool = False, overwrite: bool = False, first_session: int = 0) -> Path:
    """Simulate ``sessions`` sessions of ``duration_s`` s and write the dataset to ``out``.

    ``first_session`` = f writes sessions f .. f + sessions - 1: exactly the sessions (and the same
    buildings) that a run with ``sessions`` = f + sessions would write from that index on, so a second
    dataset of the same buildings (e.g. survey walks for training) never repeats a session of the first.

    An existing non-empty ``out`` is an error unless ``overwrite`` and it holds a dataset (dataset.yaml),
    which is then replaced as a whole (so no session of an earlier run is left behind).
    """
    if sessions < 1 or duration_s <= 0:
        raise ValueError(f"need sessions >= 1 and duration_s > 0 (got {sessions}, {duration_s})")
    if first_session < 0:
        raise ValueError(f"need first_session >= 0 (got {first_session})")
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        if not overwrite:
            raise ValueError(f"output folder {out} is not empty; choose another out= or pass overwrite=true")
        if not (out / "dataset.yaml").is_file():
            raise ValueError(f"output folder {out} is not empty and holds no dataset; refusing to overwrite it")
        shutil.rmtree(out)
    root_ss = np.random.SeedSequence(seed)
    b_ss, s_ss = root_ss.spawn(2)
    b_children = b_ss.spawn(cfg.buildings)
    write_dataset_meta(out, cfg.name, cfg.description or f"blenav-sim preset {cfg.name}", "CC0-1.0",
                       f"blenav-sim sim={cfg.name} seed={seed} duration_s={duration_s} sessions={sessions}"
                       + (f" first_session={first_session}" if first_session else ""),
                       simulator=sim_parameters(cfg, seed))  # the PCRLB of blenav.eval.pcrlb reads them back
    worlds = []
    for k in range(cfg.buildings):
        w = build_world(cfg, k, b_children[k])
        write_world(out, cfg, w, np.random.default_rng(b_children[k].spawn(1)[0]))
        worlds.append(w)
    it = range(first_session, first_session + sessions)
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc=f"simulating {cfg.name}", unit="session")
    # children are keyed by index: spawning first + sessions and dropping the first ones gives session i
    # the same SeedSequence as in a run from 0
    for i, ss in zip(it, s_ss.spawn(first_session + sessions)[first_session:]):
        meta, streams = simulate_session(cfg, worlds[i % len(worlds)], i, duration_s, ss)
        write_session(out, f"s{i:03d}_{meta['device_model']}_{meta['carrier']}", meta, streams)
    return out
