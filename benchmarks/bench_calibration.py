"""Calibration benchmark (issue 5): synthetic sites with known truth, KITTI, and the A9 sample.

1. Synthetic roadside sites (``xcalib.data.synth``), 20 frames each, no initial guess:
   success rate and pose error vs 2D box noise (0.5 / 1 / 2 / 4 px) with 10 % missed and 5 %
   false 2D detections. The 3D boxes are exact here (``center_noise_m = size_noise_frac =
   yaw_noise_deg = 0``); one extra row uses the generator's default 3D-detection noise.
   A "wrong" success is one with a rotation error > 1 deg or a translation error > 0.5 m.
   Uncertainty calibration: the fraction of successes whose rotation / translation error is
   within 2x the reported 1-sigma (the norm of the per-axis sigmas). Every seed drawn is also
   counted (identifiable or not): correct successes / failures / wrong successes.
   Sites are drawn from seeds 0, 1, 2, ... until ``--sites`` of them are *identifiable*: at
   least 3 distinct objects seen by both sensors and 20 true 2D-3D detections over the 20
   frames (ground truth of the generator). Sites that are not (the camera sees 0-2 objects)
   are calibrated too and must fail with a message: they are counted separately.
2. KITTI frames 000001-000005 (one shared calibration): ``T_cam_lidar`` (camera 2) from the
   label boxes with P2 as intrinsics, compared with the file's Tr_velo_to_cam.
3. A9 sample (16 real frames, no labels): residuals, matched pairs, box-centre offset, and the
   time of ``calibrate`` on the 16 loaded frames (median of ``--repeat`` runs).

Prints tables and writes ``benchmarks/results/calibration.json``.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibration.py [--sites 50] [--quick] [--parts a9,kitti]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("XCALIB_SHARED_DATA", REPO.parent / "shared" / "data"))
OUT = REPO / "benchmarks" / "results" / "calibration.json"
NOISE_3D_OFF = dict(center_noise_m=0.0, size_noise_frac=0.0, yaw_noise_deg=0.0)


def truth_counts(frames) -> tuple[int, int, int]:
    """(distinct objects seen by both sensors, true 2D-3D detections, most true ones in one frame)."""
    ids, n_true, most = set(), 0, 0
    for f in frames:
        rows = np.flatnonzero(f.match_matrix.any(1))
        n_true += len(rows)
        most = max(most, len(rows))
        ids.update(int(f.meta["ids_2d"][i]) for i in rows)
    return len(ids), n_true, most


def _identifiable(frames) -> tuple[bool, int, int]:
    """(identifiable, distinct objects seen by both sensors, true 2D-3D detections)."""
    n_obj, n_true, _ = truth_counts(frames)
    return n_obj >= 3 and n_true >= 20, n_obj, n_true


def machine_info() -> dict:
    """Interpreter, platform, CPU count and OMP threads, stored with every result file."""
    return {"python": sys.version.split()[0], "platform": platform.platform(), "cpus": os.cpu_count(),
            "omp_threads": os.environ.get("OMP_NUM_THREADS")}


def write_result(out: Path, result: dict) -> None:
    """Write ``result`` as JSON to ``out`` (folders created; atomically: a temporary file renamed)
    with a ``provenance`` stamp (xcalib version, git commit, command; ``_provenance.provenance``)
    and say where."""
    from _provenance import provenance

    out.parent.mkdir(parents=True, exist_ok=True)
    result = {**result, "provenance": result.get("provenance") or provenance()}
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(result, indent=2, default=float))
    os.replace(tmp, out)
    print(f"\nwrote {out}")


def synthetic_record(seed: int, noise: dict, n_frames: int) -> dict:
    """One synthetic roadside site (``seed``, 2D/3D ``noise``, ``n_frames`` frames) calibrated: the
    per-site record of the synthetic table (also recomputed by tests/test_results_fresh.py)."""
    from xcalib.calib.api import calibrate
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(seed, preset="roadside")
    frames = generate_frames(site, n_frames, seed=seed, render_images=False, lidar=False,
                             miss_rate_2d=0.1, false_positive_rate_2d=0.05, **noise)
    ident, n_obj, n_true = _identifiable(frames)
    t0 = time.perf_counter()
    res = calibrate(frames, frames[0].intrinsics)
    dt = time.perf_counter() - t0
    rec = {"seed": seed, "identifiable": ident, "objects": n_obj, "true_pairs": n_true,
           "success": bool(res.success), "time_s": dt, "message": res.message,
           "n_pairs": res.n_pairs, "n_2d": int(sum(f.num_2d for f in frames))}
    if res.success:
        rec["rot_deg"], rec["trans_m"] = res.pose_error(frames[0].extrinsics)
        rec["rot_std_deg"] = float(np.max(res.rotation_std_deg))
        rec["trans_std_m"] = float(np.max(res.translation_std_m))
        # 1-sigma length of the error vector (norm of the per-axis sigmas)
        rec["rot_sigma_deg"] = float(np.linalg.norm(res.rotation_std_deg))
        rec["trans_sigma_m"] = float(np.linalg.norm(res.translation_std_m))
        rec["rot_within_2sigma"] = bool(rec["rot_deg"] <= 2 * rec["rot_sigma_deg"])
        rec["trans_within_2sigma"] = bool(rec["trans_m"] <= 2 * rec["trans_sigma_m"])
    return rec


def _synthetic(n_sites: int, levels, n_frames: int, log) -> list[dict]:
    rows = []
    configs = [(f"{px:g} px, 3D exact", dict(box_noise_px=px, **NOISE_3D_OFF)) for px in levels]
    configs.append(("1 px, synth default 3D noise", dict(box_noise_px=1.0)))
    for name, noise in configs:
        recs = []
        seed = 0
        while sum(r["identifiable"] for r in recs) < n_sites:
            rec = synthetic_record(seed, noise, n_frames)
            recs.append(rec)
            ident, dt = rec["identifiable"], rec["time_s"]
            log(f"  {name:>30} site {seed:3d}{'' if ident else ' (not identifiable)'}: "
                f"{'ok ' if rec['success'] else 'FAIL'} "
                + (f"{rec['rot_deg']:.4f} deg {rec['trans_m']:.4f} m" if rec["success"] else rec["message"][:60])
                + f"  ({dt:.1f} s)")
            seed += 1
        idr = [r for r in recs if r["identifiable"]]
        ok = [r for r in idr if r["success"]]
        rot = np.array([r["rot_deg"] for r in ok]) if ok else np.zeros(0)
        tr = np.array([r["trans_m"] for r in ok]) if ok else np.zeros(0)
        wrong = int(np.sum((rot > 1.0) | (tr > 0.5)))
        non = [r for r in recs if not r["identifiable"]]
        non_wrong = sum(1 for r in non if r["success"] and (r["rot_deg"] > 1.0 or r["trans_m"] > 0.5))
        all_ok = [r for r in recs if r["success"]]
        all_wrong = sum(1 for r in all_ok if r["rot_deg"] > 1.0 or r["trans_m"] > 0.5)
        rows.append({
            "config": name, "noise": noise, "sites": len(idr), "frames": n_frames,
            "success_rate": len(ok) / max(len(idr), 1), "wrong_successes": wrong,
            "rot_deg_median": float(np.median(rot)) if len(rot) else None,
            "rot_deg_p90": float(np.percentile(rot, 90)) if len(rot) else None,
            "trans_m_median": float(np.median(tr)) if len(tr) else None,
            "trans_m_p90": float(np.percentile(tr, 90)) if len(tr) else None,
            "time_s_median": float(np.median([r["time_s"] for r in idr])),
            "non_identifiable_sites": len(non),
            "non_identifiable_failed": sum(1 for r in non if not r["success"]),
            "non_identifiable_wrong_successes": non_wrong,
            # uncertainty calibration over the identifiable successes: fraction whose true error is
            # within 2x the reported 1-sigma (norm of the per-axis sigmas); ~0.9-0.95 is honest
            "rot_within_2sigma": float(np.mean([r["rot_within_2sigma"] for r in ok])) if ok else None,
            "trans_within_2sigma": float(np.mean([r["trans_within_2sigma"] for r in ok])) if ok else None,
            "err_over_sigma_rot_median": float(np.median([r["rot_deg"] / r["rot_sigma_deg"] for r in ok])) if ok else None,
            "err_over_sigma_trans_median": float(np.median([r["trans_m"] / r["trans_sigma_m"] for r in ok])) if ok else None,
            # every seed drawn (identifiable or not)
            "all_seeds": len(recs), "all_seeds_success": len(all_ok) - all_wrong,
            "all_seeds_failed": len(recs) - len(all_ok), "all_seeds_wrong_successes": all_wrong,
            "failures": [{"seed": r["seed"], "message": r["message"], "objects": r["objects"],
                          "true_pairs": r["true_pairs"]} for r in idr if not r["success"]],
            "per_site": recs,
        })
    return rows


def kitti_row() -> dict | None:
    root = SHARED / "kitti" / "openpcdet_pr653" / "training"
    if not root.exists():
        return None
    from xcalib.calib.api import calibrate
    from xcalib.formats.kitti import kitti_frames
    from xcalib.geometry import pose_error

    seq = kitti_frames(root, ids=[1, 2, 3, 4, 5])
    frames = [seq[i] for i in range(len(seq))]
    cal = frames[0].meta["kitti_calibration"]
    t0 = time.perf_counter()
    res = calibrate(frames, frames[0].intrinsics)
    dt = time.perf_counter() - t0
    out = {"frames": seq.ids, "n_2d": int(sum(f.num_2d for f in frames)), "success": bool(res.success),
           "message": res.message, "time_s": dt, "n_pairs": res.n_pairs}
    if res.success:
        est = cal.with_T_cam_lidar(res.extrinsics)
        out["Tr_velo_to_cam_error"] = dict(zip(("rot_deg", "trans_m"), pose_error(est.Tr_velo_to_cam, cal.Tr_velo_to_cam)))
        out["T_cam2_lidar_error"] = dict(zip(("rot_deg", "trans_m"), res.pose_error(frames[0].extrinsics)))
        out.update(residual_px_median=res.residual_px_median, iou_median=res.iou_median,
                   rotation_std_deg=res.rotation_std_deg.tolist(), translation_std_m=res.translation_std_m.tolist(),
                   Tr_velo_to_cam_estimate=est.Tr_velo_to_cam.tolist())
    return out


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children (a calibration's fork pool)."""
    import resource

    me, ch = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + ch.ru_utime + ch.ru_stime


def a9_row(repeat: int) -> dict | None:
    root = SHARED / "a9_sample"
    if not root.exists():
        return None
    from xcalib.calib.api import calibrate
    from xcalib.io.frames import read_frames

    seq = read_frames(root)
    t0 = time.perf_counter()
    frames = [seq[i] for i in range(len(seq))]
    t_read = time.perf_counter() - t0
    times, cpu = [], []
    res = None
    load = os.getloadavg()[0]
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), _cpu_s()
        res = calibrate(frames, seq.intrinsics)
        times.append(time.perf_counter() - t0)
        cpu.append(_cpu_s() - c0)
    return {"frames": len(frames), "success": bool(res.success), "message": res.message,
            "read_s": t_read, "calibrate_s_median": statistics.median(times), "calibrate_s_min": min(times),
            "calibrate_s_all": times, "calibrate_cpu_s_median": statistics.median(cpu),
            "load_average_1min": [load, os.getloadavg()[0]],
            "n_pairs": res.n_pairs, "n_inliers_iou50": res.n_inliers,
            "n_2d": res.diagnostics.n_2d, "n_3d": res.diagnostics.n_3d,
            "residual_px_median": res.residual_px_median, "residual_px_mean": res.reproj_error_px,
            "iou_median": res.iou_median, "iou_mean": res.iou_mean,
            "centre_offset_px_median": res.diagnostics.centre_offset_px_median,
            "reference_centre_offset_px_median": 30.0,
            "rotation_std_deg": res.rotation_std_deg.tolist(), "translation_std_m": res.translation_std_m.tolist(),
            "T_cam_lidar": res.extrinsics.tolist()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sites", type=int, default=50)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--levels", type=float, nargs="+", default=[0.5, 1.0, 2.0, 4.0])
    ap.add_argument("--repeat", type=int, default=3, help="A9 timing repeats")
    ap.add_argument("--quick", action="store_true", help="5 sites, for a smoke run")
    ap.add_argument("--skip-synth", action="store_true")
    ap.add_argument("--verbose", action="store_true")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--parts", default="a9,kitti,synthetic",
                    help="parts to run (comma-separated); the others are kept from --out, each part with "
                         "the provenance of the run that made it (parts_provenance)")
    args = ap.parse_args(argv)
    n_sites = 5 if args.quick else args.sites
    log = (lambda s: print(s, flush=True)) if args.verbose else (lambda s: None)
    parts = {p.strip() for p in args.parts.split(",") if p.strip()}
    if args.skip_synth:
        parts.discard("synthetic")
    if unknown := parts - {"a9", "kitti", "synthetic"}:
        ap.error(f"unknown part(s) {sorted(unknown)}: a9, kitti, synthetic")

    from _provenance import provenance

    old = json.loads(args.out.read_text()) if args.out.is_file() and parts != {"a9", "kitti", "synthetic"} else {}
    now = provenance(argv)
    result = {"machine": machine_info(), "provenance": now,
              "parts_provenance": {p: (now if p in parts else (old.get("parts_provenance") or {}).get(p,
                                                                old.get("provenance", "before provenance stamps")))
                                   for p in ("a9", "kitti", "synthetic")}}
    result["a9"] = a9_row(args.repeat) if "a9" in parts else old.get("a9")
    result["kitti"] = kitti_row() if "kitti" in parts else old.get("kitti")
    result["synthetic"] = (_synthetic(n_sites, args.levels, args.frames, log) if "synthetic" in parts
                           else old.get("synthetic", []))

    print("\nSynthetic roadside sites (20 frames, 10% missed + 5% false 2D boxes, no initial guess; "
          "rot in deg, trans in m;\n'wrong' = successes off by > 1 deg or > 0.5 m; non-identifiable sites "
          "(< 3 objects or < 20 true pairs) must fail)")
    print(f"{'config':>30} {'sites':>5} {'success':>8} {'wrong':>5} {'rot med':>9} {'rot p90':>9} "
          f"{'trans med':>9} {'trans p90':>9} {'time med':>8} {'non-ident. failed':>17} {'<=2sig r/t':>11} "
          f"{'all seeds ok/failed/wrong':>26}")
    for r in result["synthetic"]:
        f = (lambda v, d=4: "-" if v is None else f"{v:.{d}f}")
        print(f"{r['config']:>30} {r['sites']:>5} {r['success_rate'] * 100:>7.1f}% {r['wrong_successes']:>5} "
              f"{f(r['rot_deg_median']):>9} {f(r['rot_deg_p90']):>9} {f(r['trans_m_median']):>9} "
              f"{f(r['trans_m_p90']):>9} {r['time_s_median']:>7.2f}s "
              f"{r['non_identifiable_failed']:>8}/{r['non_identifiable_sites']:<8} "
              f"{f(r['rot_within_2sigma'], 2):>5}/{f(r['trans_within_2sigma'], 2):<5} "
              f"{r['all_seeds_success']:>12}/{r['all_seeds_failed']}/{r['all_seeds_wrong_successes']} of {r['all_seeds']}")
    k = result["kitti"]
    if k:
        print("\nKITTI 000001-000005 (label boxes, P2):", "OK" if k["success"] else f"FAILED ({k['message']})")
        if k["success"]:
            e = k["Tr_velo_to_cam_error"]
            print(f"  Tr_velo_to_cam error: {e['rot_deg']:.4f} deg, {e['trans_m']:.4f} m; {k['n_pairs']} pairs; "
                  f"residual {k['residual_px_median']:.2f} px; {k['time_s']:.2f} s")
    a = result["a9"]
    if a:
        print("\nA9 sample (16 real frames, no labels):", "OK" if a["success"] else f"FAILED ({a['message']})")
        print(f"  calibrate: {a['calibrate_s_median']:.2f} s median of {len(a['calibrate_s_all'])} "
              f"(min {a['calibrate_s_min']:.2f} s; reading the frames {a['read_s']:.2f} s); CPU "
              f"{a.get('calibrate_cpu_s_median', float('nan')):.2f} s median; load average {a.get('load_average_1min')}")
        print(f"  pairs {a['n_pairs']} ({a['n_inliers_iou50']} with IoU>=0.5) of {a['n_2d']} 2D / {a['n_3d']} 3D boxes")
        print(f"  edge residual {a['residual_px_median']:.2f} px median ({a['residual_px_mean']:.2f} mean), "
              f"IoU {a['iou_median']:.3f} median; box-centre offset {a['centre_offset_px_median']:.1f} px median "
              f"(reference: ~30 px)")
    write_result(args.out, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
