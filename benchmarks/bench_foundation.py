"""Foundation benchmark: frame loading (A9 ASCII PCD + PNG), the same cloud as binary PCD, and
points-in-boxes for 100k points x 32 boxes.

Prints a table and writes ``benchmarks/results/foundation.json``. Targets (issue 2): binary PCD
load >= 20x faster than ASCII; points-in-boxes <= 5 ms. Without ``../shared/data/a9_sample`` a
synthetic 43.6k-point cloud and 1920x1200 image stand in (the JSON says which).

    .venv/bin/python benchmarks/bench_foundation.py [--repeat 20]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("XCALIB_SHARED_DATA", REPO.parent / "shared" / "data"))
OUT = REPO / "benchmarks" / "results" / "foundation.json"


def _time(fn, repeat: int, warmup: int = 2) -> dict:
    for _ in range(warmup):
        fn()
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return {"median_ms": statistics.median(ts), "min_ms": min(ts), "max_ms": max(ts), "repeat": repeat}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)

    from xcalib.geometry import points_in_boxes
    from xcalib.io import read_image, read_point_cloud, write_image, write_pcd

    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory(prefix="xcalib-bench-") as tmp:
        tmp = Path(tmp)
        frame = SHARED / "a9_sample" / "frame_0000"
        if (frame / "point_cloud.pcd").exists():
            source = str(frame)
            ascii_pcd, png = frame / "point_cloud.pcd", frame / "image.png"
        else:
            source = "synthetic (a9_sample absent)"
            pts = rng.normal(0, 20, size=(43_623, 3)).astype(np.float32)
            ascii_pcd, png = tmp / "cloud_ascii.pcd", tmp / "image.png"
            write_pcd(ascii_pcd, pts, encoding="ascii")
            write_image(png, rng.integers(0, 256, size=(1200, 1920, 3), dtype=np.uint8))
        cloud = read_point_cloud(ascii_pcd)
        binary_pcd = write_pcd(tmp / "cloud_binary.pcd", cloud, encoding="binary")
        compressed_pcd = write_pcd(tmp / "cloud_binary_compressed.pcd", cloud, encoding="binary_compressed")
        assert np.array_equal(read_point_cloud(binary_pcd).points, cloud.points)

        rows = {
            "pcd_ascii_load": _time(lambda: read_point_cloud(ascii_pcd), max(5, args.repeat // 2)),
            "pcd_binary_load": _time(lambda: read_point_cloud(binary_pcd), args.repeat * 5),
            "pcd_binary_compressed_load": _time(lambda: read_point_cloud(compressed_pcd), args.repeat * 5),
            "png_1920x1200_load": _time(lambda: read_image(png), max(5, args.repeat // 2)),
        }
        rows["a9_frame_load_ascii_pcd_plus_png"] = _time(
            lambda: (read_point_cloud(ascii_pcd), read_image(png)), max(5, args.repeat // 2))

    # points-in-boxes: 100k points, 32 boxes with yaw, 1.25x expansion (protocol default)
    P, M = 100_000, 32
    pts = np.column_stack([rng.uniform(-60, 60, P), rng.uniform(-60, 60, P), rng.uniform(-3, 5, P),
                           rng.uniform(0, 1, P)]).astype(np.float32)
    boxes = np.column_stack([rng.uniform(-50, 50, (M, 2)), rng.uniform(-1, 1, M), rng.uniform(3, 6, M),
                             rng.uniform(1.6, 2.2, M), rng.uniform(1.4, 2.0, M), rng.uniform(-np.pi, np.pi, M)])
    rows["points_in_boxes_100k_x_32"] = _time(lambda: points_in_boxes(pts, boxes, expansion=1.25), args.repeat * 2)

    speedup = rows["pcd_ascii_load"]["median_ms"] / rows["pcd_binary_load"]["median_ms"]
    pib = rows["points_in_boxes_100k_x_32"]["median_ms"]
    targets = {
        "binary_vs_ascii_speedup": {"value": speedup, "target": ">= 20", "met": bool(speedup >= 20)},
        "points_in_boxes_ms": {"value": pib, "target": "<= 5", "met": bool(pib <= 5.0)},
    }
    from _provenance import provenance

    result = {
        "benchmark": "foundation", "source": source, "num_points": cloud.num_points, "provenance": provenance(argv),
        "timings": rows, "targets": targets,
        "env": {"python": platform.python_version(), "numpy": np.__version__, "machine": platform.machine(),
                "cpu_count": os.cpu_count(), "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
                "time": time.strftime("%Y-%m-%dT%H:%M:%S")},
    }

    print(f"foundation benchmark ({source}, {cloud.num_points} points)")
    print(f"{'case':<36}{'median ms':>12}{'min ms':>10}{'max ms':>10}")
    for name, r in rows.items():
        print(f"{name:<36}{r['median_ms']:>12.3f}{r['min_ms']:>10.3f}{r['max_ms']:>10.3f}")
    for name, t in targets.items():
        print(f"{name:<36}{t['value']:>12.2f}  target {t['target']:<6} {'met' if t['met'] else 'NOT MET'}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
