"""Synthetic site generation and HDF5 cache throughput.

1. Generate N roadside frames at 1920x1200 (images + LiDAR + JPEG) into a cache, end to end
   (site sampling and background rendering included). Target (issue 3): 200 frames <= 60 s.
2. Labels-only mode (no images, no LiDAR): 50 sites x 20 frames, as the calibration studies use.
3. Read labels + points of R frames from a cache (``read_images=False``). Target: >= 500 frames/s.

Prints a table and writes ``benchmarks/results/synth_cache.json``.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_synth_cache.py [--frames 200] [--read-frames 1000]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "benchmarks" / "results" / "synth_cache.json"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--read-frames", type=int, default=1000)
    ap.add_argument("--sites", type=int, default=50)
    ap.add_argument("--site-frames", type=int, default=20)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)

    from xcalib.data.synth import iter_frames, sample_site
    from xcalib.data.synth.detections import camera_view, detect
    from xcalib.data.synth.lidar import scan
    from xcalib.data.synth.render import render_frame
    from xcalib.data.synth.scene import simulate_traffic
    from xcalib.io.hdf5 import CacheReader, CacheWriter
    from xcalib.io.images import encode_jpeg

    res: dict = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                             "omp_threads": os.environ.get("OMP_NUM_THREADS"),
                             "load_average_at_start": os.getloadavg()[0]}}
    rows = []
    with tempfile.TemporaryDirectory(prefix="xcalib-bench-synth-") as tmp:
        tmp = Path(tmp)
        # 1) full generation into a cache
        t0, c0 = time.perf_counter(), time.process_time()
        site = sample_site(0, "roadside")
        _ = site.background
        t_site = time.perf_counter() - t0
        n_pts = []
        with CacheWriter(tmp / "full.h5", camera_names=[site.camera_name], jpeg_quality=site.config.jpeg_quality) as w:
            for f in iter_frames(site, args.frames, seed=1):
                n_pts.append(len(f.point_cloud))
                w.add(f)
        t_full = time.perf_counter() - t0
        c_full = time.process_time() - c0
        size_mb = (tmp / "full.h5").stat().st_size / 1e6
        res["generate_full"] = {"frames": args.frames, "width": site.width, "height": site.height,
                                "seconds": t_full, "cpu_seconds": c_full, "site_and_background_s": t_site,
                                "frames_per_s": args.frames / t_full, "mean_points": float(np.mean(n_pts)),
                                "cache_mb": size_mb, "target_s": 60.0, "ok": t_full <= 60.0,
                                "points_per_frame": [int(n) for n in n_pts]}
        rows.append((f"generate {args.frames} frames 1920x1200 + LiDAR + JPEG -> cache",
                     f"{t_full:.1f} s (cpu {c_full:.1f} s)",
                     "<= 60 s", t_full <= 60.0))
        # per-stage breakdown on 20 frames
        tracks = simulate_traffic(site, 20, np.random.default_rng(0))
        st = {"labels": 0.0, "render": 0.0, "lidar": 0.0, "jpeg": 0.0}
        for k in range(20):
            objs = tracks.at(k)
            a = time.perf_counter()
            view = camera_view(site, objs)
            detect(site, objs, np.random.default_rng(k), view=view)
            b = time.perf_counter()
            img = render_frame(site, objs, view)
            c = time.perf_counter()
            scan(site, objs, np.random.default_rng(k))
            d = time.perf_counter()
            encode_jpeg(img, site.config.jpeg_quality)
            e = time.perf_counter()
            st["labels"] += b - a
            st["render"] += c - b
            st["lidar"] += d - c
            st["jpeg"] += e - d
        res["stage_ms_per_frame"] = {k: v / 20 * 1e3 for k, v in st.items()}
        for k, v in res["stage_ms_per_frame"].items():
            rows.append((f"  stage: {k}", f"{v:.1f} ms/frame", "", None))
        # 2) labels-only: many sites
        t0 = time.perf_counter()
        n = 0
        for s in range(args.sites):
            st_ = sample_site(100 + s, "roadside")
            for _ in iter_frames(st_, args.site_frames, seed=s, render_images=False, lidar=False):
                n += 1
        t_lab = time.perf_counter() - t0
        res["labels_only"] = {"sites": args.sites, "frames_per_site": args.site_frames, "seconds": t_lab,
                              "frames_per_s": n / t_lab}
        rows.append((f"labels-only {args.sites} sites x {args.site_frames} frames", f"{t_lab:.1f} s "
                     f"({n / t_lab:.0f} frames/s)", "", None))
        # 3) read labels + points from a cache of R frames (LiDAR, no images)
        site2 = sample_site(1, "roadside")
        t0 = time.perf_counter()
        with CacheWriter(tmp / "read.h5", camera_names=[site2.camera_name]) as w:
            for f in iter_frames(site2, args.read_frames, seed=2, render_images=False):
                f.image = np.zeros((0, 0, 3), np.uint8)
                w.add(f)
        t_write = time.perf_counter() - t0
        fps_wall, fps_cpu, fps_x_wall, fps_x_cpu = 0.0, 0.0, 0.0, 0.0
        for _ in range(3):  # best of 3 passes (the machine is shared)
            t0, c0 = time.perf_counter(), time.process_time()
            with CacheReader(tmp / "read.h5", read_images=False, read_extras=False) as r:
                for f in r:
                    pass
            fps_wall = max(fps_wall, args.read_frames / (time.perf_counter() - t0))
            fps_cpu = max(fps_cpu, args.read_frames / (time.process_time() - c0))
            t0, c0 = time.perf_counter(), time.process_time()
            with CacheReader(tmp / "read.h5", read_images=False) as r:  # + box7, ids, classes, clean boxes
                for f in r:
                    pass
            fps_x_wall = max(fps_x_wall, args.read_frames / (time.perf_counter() - t0))
            fps_x_cpu = max(fps_x_cpu, args.read_frames / (time.process_time() - c0))
        t0 = time.perf_counter()
        total_pts = 0
        with CacheReader(tmp / "read.h5", read_images=False, read_extras=False) as r:
            for f in r:
                total_pts += len(f.point_cloud) + f.num_2d + f.num_3d
        t_read = time.perf_counter() - t0
        fps = max(fps_wall, args.read_frames / t_read)
        res["read_labels_points"] = {"frames": args.read_frames, "seconds_first_pass": t_read, "frames_per_s": fps,
                                     "frames_per_cpu_s": fps_cpu, "with_extras_frames_per_s": fps_x_wall,
                                     "with_extras_frames_per_cpu_s": fps_x_cpu,
                                     "mean_points_per_frame": total_pts / args.read_frames,
                                     "cache_mb": (tmp / "read.h5").stat().st_size / 1e6,
                                     "write_seconds_incl_generation": t_write, "target_fps": 500.0,
                                     "ok": fps >= 500.0}
        rows.append((f"read labels+points of {args.read_frames} frames", f"{fps:.0f} frames/s (cpu {fps_cpu:.0f})",
                     ">= 500", fps >= 500))
        rows.append(("  ... plus xcalib extras (box7, ids, classes, clean boxes)",
                     f"{fps_x_wall:.0f} frames/s (cpu {fps_x_cpu:.0f})", "", None))
    w1 = max(len(r[0]) for r in rows)
    print(f"{'measurement':<{w1}}  {'result':>24}  {'target':>8}  ok")
    for name, val, tgt, ok in rows:
        print(f"{name:<{w1}}  {val:>24}  {tgt:>8}  {'' if ok is None else ('yes' if ok else 'NO')}")
    res["machine"]["load_average_at_end"] = os.getloadavg()[0]
    print(f"load average {res['machine']['load_average_at_start']:.1f} -> {res['machine']['load_average_at_end']:.1f} "
          f"on {os.cpu_count()} cores (wall figures shrink when the machine is shared; cpu = process time)")
    from _provenance import provenance

    res["provenance"] = provenance(argv)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(res, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
