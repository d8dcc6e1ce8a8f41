#!/usr/bin/env python
"""CPU latency of ``Matcher.match`` per model (crop + forward, validation off), p50 over runs.

Sizes: K=8, M=12 (synthetic 1920x1200 frame, 43,623 points) and the A9 ``frame_0000`` size
(K=11, M=17, 43,623 points; the real frame from ../shared/data/a9_sample when present, else a
synthetic frame of that size). Configs: ``default`` = the reference-size config of
``create_model(name)`` (random weights; latency does not depend on them) and ``shipped`` =
the packaged synthetic-site weights and config. Threads: ``--threads`` (default 2).
Writes benchmarks/results/matching.json.

Usage: python benchmarks/bench_matching.py [--models ...] [--threads 2] [--runs 20]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "benchmarks" / "results" / "matching.json"
SLOW = {"crlite", "crlite_2dpe", "calibrefine"}


def synthetic_frame(K: int, M: int, n_points: int = 43623, seed: int = 0):
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 255, size=(1200, 1920, 3), dtype=np.uint8)
    c = np.column_stack([rng.uniform(8, 60, M), rng.uniform(-20, 20, M), np.full(M, -4.0)])
    dims = np.column_stack([rng.uniform(3.5, 5, M), rng.uniform(1.6, 2.2, M), rng.uniform(1.4, 2.0, M)])
    per = 300
    inside = (c[:, None] + rng.uniform(-0.5, 0.5, (M, per, 3)) * dims[:, None]).reshape(-1, 3)
    rest = rng.uniform([0, -40, -6], [80, 40, 2], size=(n_points - len(inside), 3))
    pc = np.vstack([inside, rest]).astype(np.float32)
    xy = rng.uniform([0, 300], [1700, 1000], size=(K, 2))
    wh = rng.uniform(40, 220, size=(K, 2))
    b2 = np.hstack([xy, xy + wh]).astype(np.float32)
    b3 = np.hstack([c - dims / 2, c + dims / 2]).astype(np.float32)
    return image, pc, b2, b3


def a9_frame():
    env = os.environ.get("XCALIB_SHARED_DATA")
    root = Path(env) if env else REPO.parent / "shared" / "data"
    d = root / "a9_sample" / "frame_0000"
    if not (d / "detections.json").exists():
        return synthetic_frame(11, 17, seed=1), "synthetic (A9 size)"
    from xcalib.io.frames import read_frames

    f = read_frames(d / "detections.json")[0]
    return (f.image, f.point_cloud[:, :3].astype(np.float32), f.bboxes_2d, f.bboxes_3d), f"A9 {d}"


def bench(matcher, frame, runs: int) -> dict:
    matcher.match(*frame, validate="off", geometry="off")  # warm-up
    ts = []
    for _ in range(runs):
        t0 = time.perf_counter()
        matcher.match(*frame, validate="off", geometry="off")
        ts.append((time.perf_counter() - t0) * 1000.0)
    a = np.array(ts)
    return {"p50_ms": float(np.median(a)), "mean_ms": float(a.mean()), "min_ms": float(a.min()), "runs": runs}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--models", nargs="*", default=None)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--configs", nargs="*", default=["default", "shipped"])
    ap.add_argument("--tag", default="", help="write results/matching_<tag>.json instead of matching.json")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    from xcalib.engine.checkpoint import WeightsNotFoundError
    from xcalib.engine.matcher import Matcher
    from xcalib.models import create_model, list_models

    models = args.models or list_models()
    a9, a9_source = a9_frame()
    sizes = {"K8_M12": synthetic_frame(8, 12), "A9_K11_M17": a9}
    rows = []
    for name in models:
        for kind in args.configs:
            try:
                m = (Matcher(create_model(name), device="cpu") if kind == "default"
                     else Matcher.from_pretrained(name, site="synthetic", device="cpu"))
            except WeightsNotFoundError:
                continue
            for size, frame in sizes.items():
                runs = max(3, args.runs // 5) if name in SLOW and kind == "default" else args.runs
                r = bench(m, frame, runs)
                rows.append({"model": name, "config": kind, "size": size, "points": int(len(frame[1])),
                             "parameters": m.model.num_parameters(), **r})
                print(f"{name:16s} {kind:8s} {size:11s} p50 {r['p50_ms']:9.2f} ms  (min {r['min_ms']:.2f}, "
                      f"{r['runs']} runs)", flush=True)
    ref = {(r["size"]): r["p50_ms"] for r in rows if r["model"] == "crlite" and r["config"] == "default"}
    for r in rows:
        if r["size"] in ref:
            r["speedup_vs_crlite_default"] = ref[r["size"]] / r["p50_ms"]
    print(f"load average (1/5/15 min): {os.getloadavg()}")
    print("\n| model | config | size | p50 ms | min ms | x vs crlite(default) |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['model']} | {r['config']} | {r['size']} | {r['p50_ms']:.2f} | {r['min_ms']:.2f} | "
              f"{r.get('speedup_vs_crlite_default', float('nan')):.1f} |")
    out = OUT.with_name(f"matching_{args.tag}.json") if args.tag else OUT
    out.parent.mkdir(parents=True, exist_ok=True)
    from _provenance import provenance

    out.write_text(json.dumps({"provenance": provenance(), "threads": args.threads, "torch": torch.__version__, "cpu": platform.processor() or
                               platform.machine(), "a9_source": a9_source, "loadavg_1_5_15": list(os.getloadavg()),
                               "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
