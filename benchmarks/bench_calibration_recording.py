"""Whole recordings: calibration time, frames and objects used, pose error (issue 25 item 4, issue 29).

A synthetic roadside recording (``xcalib.data.synth``: one site, ``N`` consecutive 10 Hz frames of
traffic, 1 px 2D noise, 10 % 2D misses, 5 % false 2D boxes, exact 3D boxes with track ids, no
images or clouds -- the ``synth1000`` case of ``bench_calibration_speed.py``) is calibrated with
``xcalib.calibrate`` and its defaults (``CalibConfig.max_frames`` = 200: the frame selection of
``xcalib.calib.selection`` picks the informative frames of a longer recording), one process,
``workers=1``, one fresh child process per case. Reported per case: CPU time of the call (the
figure to read on a shared machine; ``time.process_time``) and wall time, the selection's own
time (association of the objects + greedy coverage; the scan of the frames is in the call), frames
given / used, distinct objects (3D tracks) in the recording / in the used frames, the pose error
against the truth, whether it lies within the reported 2-sigma, the verdict, peak RSS.

Cases ``N`` (default 100, 1000, 2000, 5000, 1000:positions, 1000:all); ``N:positions`` strips the track ids (objects associated
by 3D position); ``N:all`` calibrates every frame (``max_frames=None``: the cost without
selection). Targets: 2,000 frames <= 120 s and 1,000 frames <= 30 s on one core, success, every
object used. ``--scaling`` also times the selection alone (budget 200) on 1,000-8,000 frames
(a 1,000-frame recording repeated): linear in the frames. Prints a table and writes ``benchmarks/results/calibration_recording.json``.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibration_recording.py \
        [--cases 100 1000 2000 5000 1000:positions 1000:all] [--seed 0] [--scaling]
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing as mp
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibration import NOISE_3D_OFF, machine_info, write_result  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "benchmarks" / "results" / "calibration_recording.json"
DEFAULT_CASES = ("100", "1000", "2000", "5000", "1000:positions", "1000:all")
WRONG_ROT_DEG, WRONG_TRANS_M = 1.0, 0.5


def recording(seed: int, n_frames: int):
    """(frames, intrinsics, truth [4,4]) of an ``n_frames`` synthetic recording of one site."""
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(seed, preset="roadside")
    frames = generate_frames(site, n_frames, seed=seed, render_images=False, lidar=False, miss_rate_2d=0.1,
                             false_positive_rate_2d=0.05, box_noise_px=1.0, **NOISE_3D_OFF)
    return frames, site.intrinsics, site.T_cam_lidar


def _child(case: str, seed: int, q) -> None:
    import resource
    import warnings

    warnings.simplefilter("ignore")
    from xcalib.calib.api import calibrate
    from xcalib.calib.config import CalibConfig

    n, _, variant = case.partition(":")
    c0 = time.process_time()
    frames, intr, T = recording(seed, int(n))
    gen_s = time.process_time() - c0
    if variant == "positions":
        frames = [dataclasses.replace(f, track_ids_3d=None) for f in frames]
    config = CalibConfig(workers=1, max_frames=None if variant == "all" else CalibConfig().max_frames)
    t0, c0 = time.perf_counter(), time.process_time()
    res = calibrate(frames, intr, config)
    rec = {"case": case, "seed": seed, "frames": int(n), "generate_cpu_s": gen_s,
           "cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - t0,
           "n_2d": int(sum(len(f.bboxes_2d) for f in frames)), "n_3d": int(sum(len(f.bboxes_3d) for f in frames))}
    s = res.diagnostics.selection
    rec.update(max_frames=config.max_frames, frames_used=s.n_frames_used, objects=s.n_objects,
               objects_used=s.n_objects_used, object_identity=s.object_identity, selection_s=s.elapsed_s,
               success=bool(res.success), refusal=res.diagnostics.refusal, message=res.message, n_pairs=res.n_pairs)
    if res.success:
        rot, tr = (float(v) for v in res.pose_error(T))
        rs, ts = float(np.linalg.norm(res.rotation_std_deg)), float(np.linalg.norm(res.translation_std_m))
        rec.update(rot_deg=rot, trans_m=tr, rot_sigma_deg=rs, trans_sigma_m=ts,
                   within_2sigma=bool(rot <= 2 * rs and tr <= 2 * ts),
                   wrong=bool(rot > WRONG_ROT_DEG or tr > WRONG_TRANS_M))
    rec["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 10
    q.put(rec)


def run_case(case: str, seed: int, timeout: float = 3600) -> dict:
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_child, args=(case, seed, q))
    p.start()
    try:
        rec = q.get(timeout=timeout)
    except Exception:  # noqa: BLE001 - a child killed by the OS or timed out
        p.kill()
        rec = {"case": case, "seed": seed, "success": False, "error": f"child died (exit {p.exitcode})"}
    p.join()
    return rec


def selection_scaling(seed: int, sizes=(1000, 2000, 4000, 8000)) -> list[dict]:
    """CPU time of ``select_frames`` (budget 200) on recordings of ``sizes`` frames, made by
    repeating a 1,000-frame recording's boxes (track ids and times shifted per repeat), with
    the track ids and with objects associated by position: the selection is linear in frames."""
    from xcalib.calib.selection import scan_frames, select_frames

    frames, _, _ = recording(seed, 1000)
    base = scan_frames(frames)
    rows = []
    for n in sizes:
        boxes = [dataclasses.replace(b, track_ids=b.track_ids + np.where(b.track_ids >= 0, 100000 * (k // 1000), 0),
                                     time_s=b.time_s + 100.0 * (k // 1000))
                 for k, b in ((k, base[k % 1000]) for k in range(n))]
        row = {"frames": n}
        for name, bx in (("tracks", boxes), ("positions", [dataclasses.replace(b, track_ids=None) for b in boxes])):
            c0 = time.process_time()
            sel = select_frames(bx, 200)
            row[f"{name}_cpu_s"] = time.process_time() - c0
            row[f"{name}_objects"], row[f"{name}_objects_used"] = sel.n_objects, sel.n_objects_used
        rows.append(row)
        print(f"  selection of {n} frames: {row['tracks_cpu_s']:.2f} s CPU with track ids "
              f"({row['tracks_objects_used']} of {row['tracks_objects']} objects), {row['positions_cpu_s']:.2f} s "
              f"by position ({row['positions_objects_used']} of {row['positions_objects']})", flush=True)
    return rows


def _f(v, nd=1):
    return "-" if v is None else f"{v:.{nd}f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(DEFAULT_CASES))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--scaling", action="store_true", help="also time the selection alone on 1,000-8,000 frames")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    t_all = time.perf_counter()
    scaling = selection_scaling(args.seed) if args.scaling else None
    recs = []
    for case in args.cases:
        rec = run_case(case, args.seed)
        recs.append(rec)
        print(f"  {case}: {'ok' if rec.get('success') else 'REFUSED'} CPU {_f(rec.get('cpu_s'))} s "
              f"(wall {_f(rec.get('wall_s'))} s), {rec.get('frames_used')} of {rec.get('frames')} frames, "
              f"{rec.get('objects_used')} of {rec.get('objects')} objects"
              + (f", {rec['rot_deg']:.3f} deg / {rec['trans_m']:.3f} m" if rec.get("success") else
                 f": {rec.get('message', rec.get('error', ''))[:80]}"), flush=True)
    print("\nWhole recordings (synthetic roadside site, 10 Hz; one process, OMP_NUM_THREADS=1; CPU = process time "
          "of xcalib.calibrate; sel wall = wall time of the selection inside it; 2sig = error within the reported "
          "2-sigma)")
    hdr = (f"{'case':>16} {'frames':>6} {'used':>5} {'objects':>7} {'obj used':>8} {'sel wall':>8} {'CPU s':>7} "
           f"{'wall s':>7} {'rot deg':>8} {'trans m':>8} {'2sig':>5} {'verdict':>9} {'RSS MB':>7}")
    print(hdr)
    for r in recs:
        verdict = "success" if r.get("success") else (r.get("refusal") or r.get("error", "?"))[:9]
        print(f"{r['case']:>16} {r.get('frames', '-'):>6} {r.get('frames_used', '-'):>5} {r.get('objects', '-'):>7} "
              f"{r.get('objects_used', '-'):>8} {_f(r.get('selection_s'), 2):>8} {_f(r.get('cpu_s')):>7} "
              f"{_f(r.get('wall_s')):>7} {_f(r.get('rot_deg'), 4):>8} {_f(r.get('trans_m'), 4):>8} "
              f"{('yes' if r['within_2sigma'] else 'no') if 'within_2sigma' in r else '-':>5} {verdict:>9} "
              f"{_f(r.get('peak_rss_mb'), 0):>7}")
    write_result(args.out, {"benchmark": "calibration_recording", "machine": machine_info(),
                            "command": "benchmarks/bench_calibration_recording.py " + " ".join(argv or sys.argv[1:]),
                            "wall_s": time.perf_counter() - t_all, "targets": {"2000_cpu_s": 120, "1000_cpu_s": 30},
                            "runs": recs, "selection_scaling": scaling})
    return 0


if __name__ == "__main__":
    sys.exit(main())
