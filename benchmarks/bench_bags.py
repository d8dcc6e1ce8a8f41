"""Bags benchmark: real samples converted to MCAP, calibrated from the MCAP, per camera vs truth.

* ``a9_sample`` (1 camera, 16 frames, no ground truth): the frame folder -> MCAP; the calibration
  from the MCAP must equal the one from the folder (same pose, same pairs).
* ``nuscenes`` (6 cameras, 1 sample, the info pickle's detections and ground truth).
* ``sustech_example`` (3 cameras, 3 frames) and ``pandaset_002`` frame 00 (6 cameras): labelled
  3D boxes; 2D boxes from :func:`xcalib.data.boxes2d.synthetic_2d_boxes` (projected with the
  ground truth, 1 px noise, 10 % missed, 5 % false, occlusion; seed 0) since neither has 2D
  detections. SUSTech's ground truth is hand-tuned (approximate).
* KITTI ``openpcdet_pr653`` (frames from two calibration days), directly from the folder, one
  day at a time with ``frames=`` (``0`` and ``1:6``).
* Timings: bag indexing (open, deserialise, index by stamp: ``BagFrames``) and frame pairing
  (``pair_by_time``) per 1000 messages, on a synthetic 600-frame MCAP with small messages, and
  the real MCAPs' indexing.

Each multi-camera sample is merged (``merge_cameras``: one LiDAR sweep, every camera's image,
CameraInfo and 2D detections, the union of the 3D boxes), written with ``write_bag`` (camera
stamps = the sample's camera times where it has them) and calibrated with ``xcalib.site.
calibrate_site`` from the MCAP (``BagFrames`` per camera, tolerance 0.12 s: PandaSet's back
camera fires 100 ms before the sweep).

Prints a table and writes ``benchmarks/results/bags.json``.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_bags.py [--skip-a9]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibration import machine_info, write_result  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
OUT = REPO / "benchmarks" / "results" / "bags.json"
NUS = DATA / "nuscenes" / "mmdet3d_demo" / "n015-2018-07-24-11-22-45+0800.pkl"
TOL_S = 0.12


def _views(source, cameras, frames=None, synth2d=False):
    from xcalib.data.boxes2d import synthetic_2d_boxes
    from xcalib.io.sources import open_source

    out = {}
    for cam in cameras:
        seq = open_source(source, camera=cam, frames=frames)
        items = [seq[i] for i in range(len(seq))]
        out[cam] = [synthetic_2d_boxes(f, seed=0) for f in items] if synth2d else items
    return out


def _site_rows(name: str, site, t_calib: float) -> list[dict]:
    rows = []
    for c in site.cameras:
        r = c.result
        err = c.error_vs_truth
        rows.append({"dataset": name, "camera": c.camera, "frames": c.num_frames, "pairs": r.n_pairs,
                     "verdict": c.verdict, "rot_err_deg": None if err is None else err[0],
                     "trans_err_m": None if err is None else err[1],
                     "rot_std_deg": float(max(r.rotation_std_deg)) if r.success else None,
                     "trans_std_m": float(max(r.translation_std_m)) if r.success else None,
                     "message": "" if r.success else r.message, "calib_s": round(t_calib, 2)})
    return rows


def _bag_site(name: str, views: dict, tmp: Path, log) -> tuple[list[dict], dict]:
    """Merge, write MCAP, read each camera back from it, calibrate the site."""
    from xcalib.io.bags import BagFrames, write_bag
    from xcalib.io.sources import merge_cameras
    from xcalib.site import calibrate_site

    t = time.perf_counter()
    merged = merge_cameras(views) if len(views) > 1 else next(iter(views.values()))
    path = write_bag(tmp / f"{name}.mcap", merged)
    t_write = time.perf_counter() - t
    from xcalib.io.bags import topic_name

    t = time.perf_counter()
    bag_views = {cam: BagFrames(path, topic_name(cam) if len(views) > 1 else None, tolerance_s=TOL_S)
                 for cam in views}
    t_index = time.perf_counter() - t
    n_msgs = sum(tp.count for tp in __import__("xcalib.io.bags", fromlist=["bag_info"]).bag_info(path).topics)
    t = time.perf_counter()
    site, loaded = calibrate_site(bag_views, source=str(path))
    t_cal = time.perf_counter() - t
    stats = {"dataset": name, "mcap_mb": round(path.stat().st_size / 1e6, 2), "messages": n_msgs,
             "write_s": round(t_write, 3), "index_all_cameras_s": round(t_index, 3),
             "index_ms_per_1000_msgs": round(1000 * t_index / len(views) / max(n_msgs, 1) * 1000, 1)}
    log(f"{name}: {path.stat().st_size / 1e6:.1f} MB MCAP, {n_msgs} messages, write {t_write:.2f} s, "
        f"index {t_index / len(views):.2f} s per camera, calibrate {t_cal:.1f} s")
    return _site_rows(name, site, t_cal), {"stats": stats, "site": site, "loaded": loaded, "path": path}


def _a9(tmp: Path, log) -> dict:
    """Folder vs MCAP: the same calibration."""
    from xcalib.calib.api import calibrate
    from xcalib.io.bags import BagFrames, write_bag
    from xcalib.io.sources import open_source

    folder = open_source(DATA / "a9_sample")
    frames = [folder[i] for i in range(len(folder))]
    t = time.perf_counter()
    path = write_bag(tmp / "a9.mcap", frames)
    t_write = time.perf_counter() - t
    t = time.perf_counter()
    bag = BagFrames(path)
    t_index = time.perf_counter() - t
    back = [bag[i] for i in range(len(bag))]
    exact = all(np.array_equal(a.image, b.image) and np.array_equal(a.point_cloud, b.point_cloud)
                and np.array_equal(a.bboxes_2d, b.bboxes_2d) and np.array_equal(a.bboxes_3d, b.bboxes_3d)
                for a, b in zip(frames, back))
    t = time.perf_counter()
    r_folder = calibrate(frames, folder.intrinsics)
    t_cal = time.perf_counter() - t
    r_bag = calibrate(back, bag.intrinsics)
    same_pairs = len(r_folder.pairs) == len(r_bag.pairs) and all(np.array_equal(a, b) for a, b in
                                                                 zip(r_folder.pairs, r_bag.pairs))
    d_T = float(np.abs(r_folder.extrinsics - r_bag.extrinsics).max())
    res = {"frames": len(frames), "frames_equal": bool(exact), "intrinsics_equal": bag.intrinsics == folder.intrinsics,
           "success_folder": r_folder.success, "success_mcap": r_bag.success, "n_pairs": r_folder.n_pairs,
           "max_abs_diff_T": d_T, "same_pairs": bool(same_pairs), "mcap_mb": round(path.stat().st_size / 1e6, 1),
           "write_s": round(t_write, 2), "index_s": round(t_index, 3), "calib_s": round(t_cal, 1)}
    log(f"a9: frames equal {exact}, folder {r_folder.success} ({r_folder.n_pairs} pairs) vs MCAP {r_bag.success} "
        f"({r_bag.n_pairs} pairs), max |dT| {d_T:.3g}, same pairs {same_pairs}")
    return res


def _timings(tmp: Path, log) -> dict:
    """Indexing and pairing per 1000 messages on a bag of many small messages."""
    from xcalib.geometry.camera import CameraIntrinsics
    from xcalib.io.bags import BagFrames, pair_by_time, write_bag
    from xcalib.types import Frame

    rng = np.random.default_rng(0)
    n = 600
    intr = CameraIntrinsics(100.0, 100.0, 32.0, 20.0, width=64, height=40)
    frames = [Frame(image=rng.integers(0, 255, (40, 64, 3), dtype=np.uint8),
                    point_cloud=rng.normal(size=(200, 4)).astype(np.float32),
                    bboxes_2d=np.array([[1, 2, 10, 12], [20, 5, 30, 25]], np.float32),
                    bboxes_3d=np.array([[5, 0, 0, 6, 1, 2], [8, 2, 0, 9, 3, 1.5]], np.float32),
                    camera_name="cam", frame_key=f"{i:05d}", intrinsics=intr,
                    point_fields=("x", "y", "z", "intensity")) for i in range(n)]
    out = {}
    for suffix in (".mcap", ".db3", ".bag"):
        path = write_bag(tmp / f"many{suffix}", frames)
        t = time.perf_counter()
        bag = BagFrames(path)
        dt = time.perf_counter() - t
        msgs = 6 * n  # points, 3D dets, image, camera_info, 2D dets, xcalib record
        out[suffix] = {"messages": msgs, "index_and_pair_s": round(dt, 3),
                       "ms_per_1000_messages": round(1000 * dt / msgs * 1000, 1), "frames": len(bag)}
        log(f"index + pair {suffix}: {msgs} messages in {dt:.2f} s = {1e6 * dt / msgs:.1f} ms per 1000 messages")
    lid = np.sort(rng.integers(0, 10**12, 50_000))
    img = lid + rng.integers(-30_000_000, 30_000_000, len(lid))
    t = time.perf_counter()
    pairs, _, _ = pair_by_time(lid, img, 50_000_000)
    dt = time.perf_counter() - t
    out["pairing"] = {"messages": 2 * len(lid), "pairs": len(pairs),
                      "ms_per_1000_messages": round(1000 * dt / (2 * len(lid)) * 1000, 2)}
    log(f"pair_by_time: {2 * len(lid)} stamps in {dt:.3f} s = {1e6 * dt / (2 * len(lid)):.2f} ms per 1000 messages")
    return out


KITTI = DATA / "kitti" / "openpcdet_pr653"
KITTI_DAYS = (("kitti 0", "0"), ("kitti 1:6", "1:6"))


def kitti_rows(name: str, frames: str) -> list[dict]:
    """The KITTI rows of one calibration day (``frames``: "0" or "1:6"), straight from the folder."""
    from xcalib.site import calibrate_site

    t = time.perf_counter()
    site, _ = calibrate_site(_views(KITTI, ["image_2"], frames=frames), source=str(KITTI))
    return _site_rows(name, site, time.perf_counter() - t)


def _print_table(rows: list[dict]) -> None:
    print(f"\n{'dataset':<9} {'camera':<19} {'frm':>3} {'pairs':>5} {'verdict':<10} {'rot err':>8} {'trans err':>9}"
          f"  message")
    for r in rows:
        re_ = "-" if r["rot_err_deg"] is None else f"{r['rot_err_deg']:.3f}"
        te = "-" if r["trans_err_m"] is None else f"{r['trans_err_m']:.3f}"
        print(f"{r['dataset']:<9} {r['camera']:<19} {r['frames']:>3} {r['pairs']:>5} {r['verdict']:<10} {re_:>8} "
              f"{te:>9}  {r['message'][:90]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--skip-a9", action="store_true", help="skip the A9 folder-vs-MCAP comparison")
    args = ap.parse_args()
    log = print
    rows, stats, a9 = [], [], None
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if not args.skip_a9 and (DATA / "a9_sample").is_dir():
            a9 = _a9(tmp, log)
        samples = [
            ("nuscenes", lambda: _views(NUS, ["CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_FRONT_LEFT", "CAM_BACK",
                                              "CAM_BACK_LEFT", "CAM_BACK_RIGHT"]), NUS.is_file()),
            ("sustech", lambda: _views(DATA / "sustech_example", ["front", "left", "right"], synth2d=True),
             (DATA / "sustech_example").is_dir()),
            ("pandaset", lambda: _views(DATA / "pandaset_002", ["front_camera", "front_left_camera",
                                                                "front_right_camera", "left_camera", "right_camera",
                                                                "back_camera"], frames="0", synth2d=True),
             (DATA / "pandaset_002").is_dir()),
        ]
        for name, make, present in samples:
            if not present:
                log(f"{name}: data not present, skipped")
                continue
            r, info = _bag_site(name, make(), tmp, log)
            rows += r
            stats.append(info["stats"])
            if name == "nuscenes":
                agreements = [a.to_dict() for a in info["site"].agreements]
        if KITTI.is_dir():  # two calibration days in one folder: frame 000000 vs 000001-000005
            for name, rng_ in KITTI_DAYS:
                rows += kitti_rows(name, rng_)
        timings = _timings(tmp, log)
    _print_table(rows)
    ok = [r for r in rows if r["verdict"] == "calibrated"]
    wrong = [r for r in ok if r["rot_err_deg"] is not None and (r["rot_err_deg"] > 1.0 or r["trans_err_m"] > 0.5)]
    print(f"\n{len(ok)} of {len(rows)} cameras calibrated, {len(wrong)} wrong (> 1 deg or > 0.5 m from the truth)")
    write_result(OUT, {"machine": machine_info(), "tolerance_s": TOL_S, "a9_folder_vs_mcap": a9, "cameras": rows,
                       "calibrated": len(ok), "wrong": len(wrong), "bags": stats,
                       "nuscenes_agreements": locals().get("agreements", []), "timings": timings})


if __name__ == "__main__":
    main()
