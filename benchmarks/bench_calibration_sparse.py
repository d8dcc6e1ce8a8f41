"""Calibration benchmark, sparse recordings: every frame shows only 1 or 2 objects to both sensors.

A quiet road or a night recording: the rig is static, the few objects are at other places in
other frames, so the pose is identifiable from the frames together but from no frame alone.
Synthetic roadside sites (``xcalib.data.synth``, default traffic), one frame every
``--stride`` generator frames (10 Hz: stride 10 = one frame a second), 1 px 2D noise, 10 %
missed and 5 % false 2D boxes, exact 3D boxes (``--noisy-3d``: the generator's default 3D
noise). Each frame is then *thinned*: of the objects seen by both sensors it keeps 1 or 2
(drawn per frame; ``--max-shared 1``: exactly 1), at most one LiDAR-only 3D box, and the false
2D boxes.

Every seed is calibrated with no initial guess. "ident." sites have 3+ distinct objects seen
by both sensors over the recording and 10+ true pairs; the rest must fail. A "wrong" success is
one with a rotation error > 1 deg or a translation error > 0.5 m (must be 0).

Prints a table and writes ``benchmarks/results/calibration_sparse.json``.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibration_sparse.py [--seeds 20] [--frames 20 40]
        [--max-shared 2 1] [--noisy-3d] [--verbose]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibration import NOISE_3D_OFF, machine_info, truth_counts, write_result  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "benchmarks" / "results" / "calibration_sparse.json"


def thin_frame(frame, rng: np.random.Generator, max_shared: int = 2, max_lidar_only: int = 1):
    """Copy of a synthetic ``Frame`` keeping 1..``max_shared`` objects seen by both sensors
    (drawn), at most ``max_lidar_only`` LiDAR-only 3D boxes and every false 2D box."""
    from xcalib.types import Frame

    mm = np.asarray(frame.match_matrix, bool)
    ids2, ids3 = np.asarray(frame.meta["ids_2d"]), np.asarray(frame.meta["ids_3d"])
    shared = np.unique(ids2[mm.any(1)])
    keep_n = int(rng.integers(1, max_shared + 1)) if len(shared) else 0
    chosen = rng.choice(shared, min(keep_n, len(shared)), replace=False) if len(shared) else np.zeros(0, int)
    only3 = np.flatnonzero(~mm.any(0) & (ids3 >= 0))
    only3 = rng.choice(only3, min(len(only3), int(rng.integers(0, max_lidar_only + 1))), replace=False) \
        if len(only3) else only3
    k2 = np.flatnonzero(np.isin(ids2, chosen) | (ids2 < 0))
    k3 = np.sort(np.concatenate([np.flatnonzero(np.isin(ids3, chosen)), only3]).astype(np.int64))
    meta = dict(frame.meta)
    for key in ("box7", "box7_gt"):
        meta[key] = np.asarray(meta[key])[k3]
    meta["ids_2d"], meta["ids_3d"] = ids2[k2], ids3[k3]
    return Frame(**{**frame.__dict__, "bboxes_2d": frame.bboxes_2d[k2], "bboxes_3d": frame.bboxes_3d[k3],
                    "match_matrix": mm[np.ix_(k2, k3)], "meta": meta})


def sparse_recording(seed: int, n_frames: int, *, stride: int = 10, noisy_3d: bool = False, max_shared: int = 2):
    """(frames, site): ``n_frames`` thinned frames, one every ``stride`` generator frames."""
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(seed, preset="roadside")
    noise = {} if noisy_3d else NOISE_3D_OFF
    raw = generate_frames(site, n_frames * stride, seed=seed, render_images=False, lidar=False,
                          miss_rate_2d=0.1, false_positive_rate_2d=0.05, box_noise_px=1.0, **noise)[::stride]
    rng = np.random.default_rng([seed, 4242])
    return [thin_frame(f, rng, max_shared=max_shared) for f in raw], site


def _truth(frames) -> tuple[bool, int, int, int]:
    """(identifiable, distinct objects seen by both, true pairs, most true pairs in one frame)."""
    n_obj, n_true, most = truth_counts(frames)
    return n_obj >= 3 and n_true >= 10, n_obj, n_true, most


def run(seeds, n_frames: int, noisy_3d: bool, stride: int, log, max_shared: int = 2) -> dict:
    from xcalib.calib.api import calibrate

    recs = []
    for seed in seeds:
        frames, site = sparse_recording(seed, n_frames, stride=stride, noisy_3d=noisy_3d, max_shared=max_shared)
        ident, n_obj, n_true, most = _truth(frames)
        t0 = time.perf_counter()
        res = calibrate(frames, site.intrinsics)
        dt = time.perf_counter() - t0
        rec = {"seed": seed, "identifiable": ident, "objects": n_obj, "true_pairs": n_true, "most_per_frame": most,
               "success": bool(res.success), "time_s": dt, "message": res.message, "n_pairs": res.n_pairs,
               "pooled": bool(res.diagnostics.pooled_search)}
        if res.success:
            rec["rot_deg"], rec["trans_m"] = res.pose_error(site.T_cam_lidar)
            rec["wrong"] = bool(rec["rot_deg"] > 1.0 or rec["trans_m"] > 0.5)
        recs.append(rec)
        log(f"  {n_frames:2d} frames{' noisy3d' if noisy_3d else ''} seed {seed:3d} "
            f"({n_obj} obj, {n_true} pairs, <= {most}/frame{'' if ident else ', not ident.'}): "
            + (f"ok {rec['rot_deg']:.3f} deg {rec['trans_m']:.3f} m" if res.success else f"FAIL {res.message[:70]}")
            + f" ({dt:.1f} s)")
    idr = [r for r in recs if r["identifiable"]]
    ok = [r for r in recs if r["success"]]
    good = [r for r in ok if not r["wrong"]]
    rot = [r["rot_deg"] for r in good]
    tr = [r["trans_m"] for r in good]
    return {
        "frames": n_frames, "stride": stride, "noisy_3d": noisy_3d, "max_shared": max_shared, "seeds": len(recs),
        "identifiable": len(idr), "success_identifiable": sum(r["success"] and not r["wrong"] for r in idr),
        "success_rate_identifiable": (sum(r["success"] and not r["wrong"] for r in idr) / len(idr)) if idr else None,
        "success_all": len(good), "wrong_successes": len(ok) - len(good),
        "non_identifiable_failed": sum(1 for r in recs if not r["identifiable"] and not r["success"]),
        "non_identifiable": len(recs) - len(idr),
        "rot_deg_median": float(np.median(rot)) if rot else None,
        "trans_m_median": float(np.median(tr)) if tr else None,
        "rot_deg_max": float(np.max(rot)) if rot else None, "trans_m_max": float(np.max(tr)) if tr else None,
        "time_s_median": float(np.median([r["time_s"] for r in recs])),
        "time_s_max": float(np.max([r["time_s"] for r in recs])),
        "per_seed": recs,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--frames", type=int, nargs="+", default=[20, 40])
    ap.add_argument("--stride", type=int, default=10)
    ap.add_argument("--max-shared", type=int, nargs="+", default=[2],
                    help="objects seen by both sensors kept per frame: 1..N (one row per value)")
    ap.add_argument("--noisy-3d", action="store_true", help="also rows with the generator's default 3D noise")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    log = (lambda s: print(s, flush=True)) if args.verbose else (lambda s: None)
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    rows = [run(seeds, n, noisy, args.stride, log, max_shared=k) for noisy in ([False, True] if args.noisy_3d else [False])
            for k in args.max_shared for n in args.frames]
    print("\nSparse roadside recordings (1..max objects per frame seen by both sensors, 1 px 2D noise, 10% missed, "
          "5% false 2D boxes;\nrot deg / trans m medians over correct successes; 'wrong' = success off by > 1 deg "
          "or > 0.5 m)")
    print(f"{'frames':>6} {'3D':>6} {'obj/fr':>6} {'seeds':>5} {'ident. ok':>10} {'all ok':>7} {'wrong':>5} {'non-id. failed':>14} "
          f"{'rot med':>8} {'trans med':>9} {'rot max':>8} {'trans max':>9} {'time med':>8} {'time max':>8}")
    f = (lambda v, d=3: "-" if v is None else f"{v:.{d}f}")
    for r in rows:
        print(f"{r['frames']:>6} {'noisy' if r['noisy_3d'] else 'exact':>6} {'1-' + str(r['max_shared']):>6} {r['seeds']:>5} "
              f"{r['success_identifiable']:>4}/{r['identifiable']:<5} {r['success_all']:>7} {r['wrong_successes']:>5} "
              f"{r['non_identifiable_failed']:>7}/{r['non_identifiable']:<6} {f(r['rot_deg_median']):>8} "
              f"{f(r['trans_m_median']):>9} {f(r['rot_deg_max']):>8} {f(r['trans_m_max']):>9} "
              f"{r['time_s_median']:>7.2f}s {r['time_s_max']:>7.2f}s")
    write_result(args.out, {"machine": machine_info(), "rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
