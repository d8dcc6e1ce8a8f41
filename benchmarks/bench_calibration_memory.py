"""Calibration benchmark, memory and time on crowded inputs (issue 12, item 6).

Synthetic roadside sites (``xcalib.data.synth``, 1 px 2D noise, exact 3D boxes), no initial
guess, each case calibrated in a fresh process whose peak RSS (``ru_maxrss``) is reported:

* ``32x270``: 20 frames, 32 2D boxes per frame (true ones, padded with false boxes) and 270 3D
  boxes per frame -- a 360-degree LiDAR: the generator's 3D boxes plus LiDAR-only boxes all
  around the sensor outside the camera's view (5-70 m, car-sized);
* ``100x100``: 10 frames, 100 2D and 100 3D boxes per frame (the old code: MemoryError at 4.9 GB);
* ``200x200``: 10 frames, 200 2D and 200 3D boxes per frame (a success or an honest refusal);
* ``dense``: the dense benchmark's 20-frame site (``bench_calibration.py``) for reference.

A child process is limited to ``--limit-gb`` of address space (the machine is shared), so a
quadratic blow-up shows as a MemoryError instead of swapping. Targets: within 2 GB, and the
32x270 case within 60 s. Prints a table and writes ``benchmarks/results/calibration_memory.json``.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibration_memory.py [--seeds 0 1 2] [--cases 32x270 200x200]

Long recordings (issue 31, item 5; ``--long``): ``xcalib calibrate`` (the command, in a child
process) on a synthetic recording of FRAMES x POINTS (``tests/_long_recording.py``: the boxes of a
synthetic site, a POINTS cloud and a 1920x1200 image made per frame when read, nothing on disk),
once with the default ``--max-memory`` and once with ``--max-memory 512M`` (refused up front);
the child's peak RSS (``ru_maxrss``), wall time, exit code and verdict or refusal are reported
(target: under 2 GB). Results go to the ``long`` key of the same JSON (the other rows are kept).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibration_memory.py --long 500 2000000
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibration import NOISE_3D_OFF, machine_info, write_result  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "benchmarks" / "results" / "calibration_memory.json"
CASES = {"32x270": (20, 32, 270), "100x100": (10, 100, 100), "200x200": (10, 200, 200), "dense": (20, 0, 0)}


def _outside_view_boxes(n: int, T: np.ndarray, intr, size, z0: float, rng) -> np.ndarray:
    """``n`` car-sized box7 [n,7] (LiDAR frame) at 5-70 m all around, whose centre the camera
    (pose T) does not see."""
    from xcalib.geometry import project_points

    out = []
    while sum(len(o) for o in out) < n:
        r, a = rng.uniform(5, 70, 4 * n), rng.uniform(-np.pi, np.pi, 4 * n)
        c = np.column_stack([r * np.cos(a), r * np.sin(a), np.full(4 * n, z0)])
        uv, z = project_points(c, intr, T[:3, :3], T[:3, 3])
        seen = (z > 0) & (uv[:, 0] > -50) & (uv[:, 0] < size[0] + 50) & (uv[:, 1] > -50) & (uv[:, 1] < size[1] + 50)
        c = c[~seen]
        out.append(np.column_stack([c, np.tile([4.5, 1.9, 1.6], (len(c), 1)), rng.uniform(-np.pi, np.pi, len(c))]))
    return np.concatenate(out)[:n]


def crowded_frames(seed: int, n_frames: int, n2: int, n3: int):
    """(frames, truth [4,4]): synthetic frames with exactly ``n2`` 2D and ``n3`` 3D boxes each."""
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.types import Frame

    site = sample_site(seed, preset="roadside", n_objects=(60, 80) if n2 else (3, 30))
    frames = generate_frames(site, n_frames, seed=seed, render_images=False, lidar=False, miss_rate_2d=0.1,
                             false_positive_rate_2d=0.05, box_noise_px=1.0, **NOISE_3D_OFF)
    if not n2:
        return frames, site.T_cam_lidar
    rng = np.random.default_rng([seed, 17])
    W, H = site.intrinsics.width, site.intrinsics.height
    out = []
    for f in frames:
        b7 = np.asarray(f.meta["box7"], dtype=np.float64)
        z0 = float(np.median(b7[:, 2])) if len(b7) else -5.0
        # the 2D boxes of objects the LiDAR sees too first (a detector finds most of them)
        seen3 = np.asarray(f.match_matrix, bool).any(1)
        order = np.r_[rng.permutation(np.flatnonzero(seen3)), rng.permutation(np.flatnonzero(~seen3))]
        b2 = f.bboxes_2d[np.sort(order[:n2])]
        if len(b2) < n2:  # pad with false 2D boxes
            k = n2 - len(b2)
            x, y = rng.uniform(0, W - 120, k), rng.uniform(0.3 * H, H - 80, k)
            b2 = np.vstack([b2, np.column_stack([x, y, x + rng.uniform(20, 120, k), y + rng.uniform(20, 80, k)])])
        b3 = b7[:n3]
        if len(b3) < n3:
            b3 = np.vstack([b3, _outside_view_boxes(n3 - len(b3), site.T_cam_lidar, site.intrinsics, (W, H), z0, rng)])
        out.append(Frame(image=f.image, point_cloud=f.point_cloud, bboxes_2d=b2, bboxes_3d=b3,
                         camera_name=f.camera_name, frame_key=f.frame_key, intrinsics=f.intrinsics,
                         extrinsics=f.extrinsics, meta={"image_size": (W, H)}))
    return out, site.T_cam_lidar


#: target objects in the scene per sequence for about N 2D boxes per frame (``junction_frames``)
JUNCTION_OBJECTS = {20: 22, 40: 45, 80: 95, 200: 650}


def junction_frames(seed: int, n_frames: int, per_side: int):
    """(frames, truth [4,4]): a busy junction seen by a wide 4K camera (100 deg, 3840x2160, 8-12 m
    up, four lanes a direction) and a 360-degree LiDAR: about ``per_side`` 2D boxes per frame (the
    generator's detections: 10 % missed, 5 % false, 1 px noise; partly occluded objects down to 5 %
    visible and 4 px are detected) and the LiDAR's 3D boxes of every object in range (exact), more
    than the 2D ones (objects all around). Unlike :func:`crowded_frames` the 2D boxes are the
    camera's view of the objects, not random padding."""
    from xcalib.data.synth import generate_frames, sample_site

    n = JUNCTION_OBJECTS.get(per_side, int(round(1.1 * per_side)))
    site = sample_site(seed, preset="roadside", n_objects=(n, n), lanes_per_direction=4, min_visible_fraction=0.05,
                       min_box_px=4.0, width=3840, height=2160, hfov_deg=(100.0, 100.0), camera_height=(8.0, 12.0))
    frames = generate_frames(site, n_frames, seed=seed, render_images=False, lidar=False, miss_rate_2d=0.1,
                             false_positive_rate_2d=0.05, box_noise_px=1.0, **NOISE_3D_OFF)
    return frames, site.T_cam_lidar


def _child(case: str, seed: int, limit_gb: float, q) -> None:
    import resource

    if limit_gb > 0:
        lim = int(limit_gb * 2 ** 30)
        resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
    q.put(calibrate_case(case, seed))


def calibrate_case(case: str, seed: int) -> dict:
    """One (case, seed) calibrated in this process: the record of the JSON's ``runs`` (peak RSS of
    this process; tests/test_results_fresh.py recomputes the cheapest one)."""
    import resource

    from xcalib.calib.api import calibrate

    n_frames, n2, n3 = CASES[case]
    frames, T = crowded_frames(seed, n_frames, n2, n3)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 10
    rec = {"case": case, "seed": seed, "frames": n_frames, "n_2d": int(sum(len(f.bboxes_2d) for f in frames)),
           "n_3d": int(sum(len(f.bboxes_3d) for f in frames)), "rss_before_mb": rss0}
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        res = calibrate(frames, frames[0].intrinsics)
        rec.update(success=bool(res.success), message=res.message, n_pairs=res.n_pairs)
        if res.success:
            rec["rot_deg"], rec["trans_m"] = res.pose_error(T)
            rec["wrong"] = bool(rec["rot_deg"] > 1.0 or rec["trans_m"] > 0.5)
    except MemoryError as exc:
        rec.update(success=False, message=f"MemoryError: {exc}", error="MemoryError")
    rec["time_s"] = time.perf_counter() - t0
    rec["cpu_s"] = time.process_time() - c0  # CPU time of the calibration (the wall time depends on the load)
    rec["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 10
    return rec


def run_case(case: str, seed: int, limit_gb: float) -> dict:
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_child, args=(case, seed, limit_gb, q))
    p.start()
    try:
        rec = q.get(timeout=1800)
    except Exception:  # noqa: BLE001 - a child killed by the OS
        rec = {"case": case, "seed": seed, "success": False, "message": f"child died (exit {p.exitcode})",
               "error": "died"}
    p.join()
    return rec


_LONG_CHILD = r"""
import json, resource, sys
from pathlib import Path
sys.path.insert(0, "tests")
from _long_recording import LongRecording
from xcalib.io.sources import register_source

def _open(path, camera=None, **options):
    spec = json.loads(Path(path).read_text())
    return LongRecording(spec["frames"], spec["points"], spec["seed"], yawless=spec["yawless"])

register_source("long-synthetic", lambda p: p.suffix == ".long", _open, priority=0)
from xcalib.cli import main
rc = main(sys.argv[1:])
print("@@" + json.dumps({"rc": rc, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run_long(n_frames: int, n_points: int, max_memory: str | None, yawless: bool, timeout: float) -> dict:
    """``xcalib calibrate`` on a synthetic FRAMES x POINTS recording in a child process."""
    import json
    import os
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory(prefix="xcalib-long-") as tmp:
        spec = Path(tmp) / "rec.long"
        spec.write_text(json.dumps({"frames": n_frames, "points": n_points, "seed": 0, "yawless": yawless}))
        out = Path(tmp) / "out"
        args = ["calibrate", str(spec), "--out", str(out), "--max-overlays", "4", "--review-max-points", "100000"]
        if max_memory is not None:
            args += ["--max-memory", max_memory]
        env = dict(os.environ, PYTHONPATH=str(REPO / "src"), OMP_NUM_THREADS="1")
        t0 = time.perf_counter()
        try:
            p = subprocess.run([sys.executable, "-c", _LONG_CHILD, *args], cwd=REPO, env=env, capture_output=True,
                               text=True, timeout=timeout)
            stdout, stderr, rc = p.stdout, p.stderr, p.returncode
        except subprocess.TimeoutExpired as exc:
            stdout, stderr, rc = str(exc.stdout or ""), str(exc.stderr or ""), None
        wall = time.perf_counter() - t0
        tail = [ln for ln in stdout.splitlines() if ln.startswith("@@")]
        rec = {"frames": n_frames, "points": n_points, "yawless": yawless, "max_memory": max_memory or "default",
               "wall_s": wall, "rc": rc}
        rec.update(json.loads(tail[-1][2:]) if tail else {"error": "no result (killed or timed out)"})
        errors = [ln for ln in stderr.splitlines() if ln.startswith("error:")]
        rec["refusal"] = errors[-1][len("error: "):] if errors else None
        cal = out / "calibration.json"
        if cal.exists():
            d = json.loads(cal.read_text())
            rec.update(success=bool(d.get("success")), message=d.get("message", ""))
    return rec


def main_long(args) -> int:
    import json

    n_frames, n_points = args.long
    recs = [run_long(n_frames, n_points, None, args.yawless, args.timeout),
            run_long(n_frames, n_points, "512M", args.yawless, args.timeout)]
    print(f"\nLong recording: xcalib calibrate on {n_frames} frames x {n_points} points (+ a 1920x1200 image each); "
          "peak RSS of the command's process")
    print(f"{'--max-memory':>12} {'exit':>4} {'peak RSS MB':>11} {'wall s':>7}  outcome")
    for r in recs:
        outcome = (r.get("refusal") or ("calibrated" if r.get("success") else f"refused: {r.get('message', '')}")
                   or r.get("error", ""))
        print(f"{r['max_memory']:>12} {str(r['rc']):>4} {r.get('peak_rss_mb', float('nan')):>11.0f} "
              f"{r['wall_s']:>7.0f}  {outcome[:160]}")
    data = json.loads(args.out.read_text()) if args.out.exists() else {}
    data["long"] = {"machine": machine_info(), "runs": recs}
    write_result(args.out, data)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=["dense", "32x270", "100x100", "200x200"], choices=list(CASES))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--limit-gb", type=float, default=6.0, help="address-space limit of each child (0: none)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--long", type=int, nargs=2, metavar=("FRAMES", "POINTS"), default=None,
                    help="only the long-recording case: xcalib calibrate on FRAMES x POINTS (e.g. 500 2000000)")
    ap.add_argument("--yawless", action="store_true", help="--long: 3D boxes without yaw (fitted to the points)")
    ap.add_argument("--timeout", type=float, default=3600.0, help="--long: seconds per run")
    args = ap.parse_args(argv)
    if args.long:
        return main_long(args)
    recs = []
    for case in args.cases:
        for seed in args.seeds:
            rec = run_case(case, seed, args.limit_gb)
            recs.append(rec)
            print(f"  {case:>8} seed {seed}: {'ok ' if rec.get('success') else 'FAIL'} "
                  f"{rec.get('time_s', float('nan')):6.1f} s (CPU {rec.get('cpu_s', float('nan')):5.1f} s), peak RSS {rec.get('peak_rss_mb', float('nan')):7.0f} MB"
                  + (f", {rec['rot_deg']:.3f} deg {rec['trans_m']:.3f} m" if rec.get("success") else
                     f", {rec.get('message', '')[:80]}"), flush=True)
    print("\nCrowded inputs (no initial guess; peak RSS of a fresh process incl. ~150 MB of imports; "
          "'wrong' = success off by > 1 deg or > 0.5 m)")
    print(f"{'case':>8} {'frames':>6} {'2D/fr':>6} {'3D/fr':>6} {'runs':>4} {'success':>7} {'wrong':>5} {'refused':>7} "
          f"{'errors':>6} {'time max':>8} {'CPU max':>8} {'RSS max MB':>10}")
    rows = []
    for case in args.cases:
        rs = [r for r in recs if r["case"] == case]
        nf, n2, n3 = CASES[case]
        row = {"case": case, "frames": nf, "runs": len(rs), "success": sum(bool(r.get("success")) for r in rs),
               "wrong": sum(bool(r.get("wrong")) for r in rs),
               "refused": sum(not r.get("success") and "error" not in r for r in rs),
               "errors": sum("error" in r for r in rs),
               "time_s_max": max((r.get("time_s", np.nan) for r in rs), default=np.nan),
               "cpu_s_max": max((r.get("cpu_s", np.nan) for r in rs), default=np.nan),
               "peak_rss_mb_max": max((r.get("peak_rss_mb", np.nan) for r in rs), default=np.nan)}
        rows.append(row)
        print(f"{case:>8} {nf:>6} {n2 or '~':>6} {n3 or '~':>6} {row['runs']:>4} {row['success']:>7} {row['wrong']:>5} "
              f"{row['refused']:>7} {row['errors']:>6} {row['time_s_max']:>7.1f}s {row['cpu_s_max']:>7.1f}s "
              f"{row['peak_rss_mb_max']:>10.0f}")
    import json

    kept = json.loads(args.out.read_text()).get("long") if args.out.exists() else None  # the --long runs stay
    write_result(args.out, {"machine": machine_info(), "limit_gb": args.limit_gb, "rows": rows, "runs": recs,
                            **({"long": kept} if kept else {})})
    return 0


if __name__ == "__main__":
    sys.exit(main())
