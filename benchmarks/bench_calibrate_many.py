"""calibrate-many over many synthetic recordings: the process pool and a local Ray cluster give the
same table (issue 29).

``--recordings`` synthetic roadside recordings (``xcalib.data.synth``: a site per seed, ``--frames``
frames each, 1 px 2D noise, exact 3D boxes) are written as frame folders into a temporary folder
and calibrated with ``xcalib.batch.calibrate_many`` three ways: serially, on a local process pool
(``--jobs``) and on a local Ray instance started here (skipped when Ray is not installed). Reported:
wall time of each, successes, wrong successes (> 1 deg / 0.5 m from the truth), and whether every
row (verdict, refusal, matches, pose) is the same for the three executors. Writes
``benchmarks/results/calibrate_many.json``.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibrate_many.py [--recordings 50] [--frames 6] [--jobs 2]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibration import NOISE_3D_OFF, machine_info, write_result  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "benchmarks" / "results" / "calibrate_many.json"


def write_recordings(root: Path, n: int, n_frames: int) -> dict[str, np.ndarray]:
    """``n`` recordings rec000.. under ``root``; returns name -> true T_cam_lidar."""
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.io.frames import write_frame_folder

    truth = {}
    for k in range(n):
        site = sample_site(k, preset="roadside")
        frames = generate_frames(site, n_frames, seed=k, render_images=False, lidar=False, miss_rate_2d=0.1,
                                 false_positive_rate_2d=0.05, box_noise_px=1.0, **NOISE_3D_OFF)
        write_frame_folder(root / f"rec{k:03d}", frames, intrinsics=site.intrinsics)
        truth[f"rec{k:03d}"] = site.T_cam_lidar
    return truth


def _key(r) -> tuple:
    return (r.name, r.success, r.refusal, r.n_pairs, r.T, bool(r.error))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", type=int, default=50)
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--executors", nargs="+", default=["serial", "process", "ray"], choices=["serial", "process", "ray"])
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    from xcalib.batch import calibrate_many

    runs = {}
    with tempfile.TemporaryDirectory(prefix="xcalib-many-") as tmp:
        root = Path(tmp)
        truth = write_recordings(root / "recs", args.recordings, args.frames)
        execs = [(e, {} if e == "serial" else {"jobs": args.jobs}) for e in args.executors]
        try:
            import ray  # noqa: F401
        except ImportError:
            execs = [e for e in execs if e[0] != "ray"]
            print("ray not installed: the Ray executor is skipped (pip install 'xcalib[ray]')")
        for name, kw in execs:
            t0 = time.perf_counter()
            s = calibrate_many([str(root / "recs" / "rec*")], root / f"out_{name}", executor=name, **kw)
            wall = time.perf_counter() - t0
            wrong = 0
            for r in s.records:
                if r.success:
                    from xcalib.calib.pose import Pose

                    rot, tr = Pose.parse(np.asarray(r.T)).error(Pose.parse(truth[r.name]))
                    wrong += int(rot > 1.0 or tr > 0.5)
            tables = all(p.is_file() for p in (s.csv, s.json, s.html))
            runs[name] = {"wall_s": wall, "success": s.n_success, "errors": s.n_error, "wrong": wrong,
                          "tables_written": tables, "rows": [_key(r) for r in s.records]}
            print(f"{name:8s} {len(s.records)} recordings: {s.n_success} calibrated ({wrong} wrong), {s.n_error} errors, "
                  f"wall {wall:.1f} s, tables {'written' if tables else 'MISSING'}", flush=True)
    first = next(iter(runs))
    same = all(runs[k]["rows"] == runs[first]["rows"] for k in runs)
    print(f"same rows for {', '.join(runs)}: {same}")
    for v in runs.values():
        v.pop("rows")
    write_result(args.out, {"benchmark": "calibrate_many", "machine": machine_info(), "recordings": args.recordings,
                            "frames": args.frames, "jobs": args.jobs, "runs": runs, "same_rows": same,
                            "command": "benchmarks/bench_calibrate_many.py " + " ".join(argv if argv is not None
                                                                                       else sys.argv[1:])})
    return 0


if __name__ == "__main__":
    sys.exit(main())
