"""Deployment benchmark: ONNX parity per model, CPU latency p50 of ONNX Runtime vs PyTorch, and
Top-1 / Top-3 / MRR of both runtimes on a small synthetic test cache.

Latency cases (single thread for both runtimes unless ``--threads``): ``K8_M12`` = model +
host scoring on prepared inputs with 8 camera and 12 LiDAR detections (the envelope's opt
shapes); ``a9`` = the whole ``match()`` (crops included) on A9 ``frame_0000`` from
``../shared/data/a9_sample`` (a synthetic 1920x1200 frame stands in when absent; the JSON says
which). Weights: the shipped ``synthetic`` site weights when present, else seeded random
weights (latency does not depend on the values; the metric table then only shows that both
runtimes agree). GPU latency is not measured here.

    .venv/bin/python benchmarks/bench_deploy.py [--models crlite fastmatch] [--repeat 20]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("XCALIB_SHARED_DATA", REPO.parent / "shared" / "data"))
OUT = REPO / "benchmarks" / "results" / "deploy.json"
MODELS = ["fastmatch", "crlite", "crlite_2dpe", "crlite_vit_exp1", "crlite_vit_exp3", "crlite_vit_exp4",
          "calibrefine"]


def _p50(fn, repeat: int, budget_s: float, warmup: int = 2) -> dict:
    for _ in range(warmup):
        fn()
    ts: list[float] = []
    t_end = time.perf_counter() + budget_s
    while len(ts) < repeat and (len(ts) < 3 or time.perf_counter() < t_end):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    return {"p50_ms": float(np.percentile(ts, 50)), "min_ms": float(min(ts)), "n": len(ts)}


def matcher_for(name: str, tmp: Path, seed: int = 0):
    import torch

    from xcalib.engine.checkpoint import WeightsNotFoundError
    from xcalib.engine.matcher import Matcher

    try:
        return Matcher.from_pretrained(name, device="cpu", site="synthetic"), "shipped (site synthetic)"
    except WeightsNotFoundError:
        torch.manual_seed(seed)
        Matcher(name, device="cpu", allow_random=True).save_pretrained(tmp / f"w_{name}")
        return Matcher.from_pretrained(name, weights=tmp / f"w_{name}", device="cpu"), f"seeded random (seed {seed})"


def _a9_frame():
    from xcalib.io.frames import read_frames

    f0 = SHARED / "a9_sample" / "frame_0000"
    if (f0 / "detections.json").is_file():
        return read_frames(f0)[0], str(f0)
    from xcalib.data.synth import generate_frames, sample_site

    return generate_frames(sample_site(0), 1, seed=0)[0], "synthetic 1920x1200 frame (a9_sample absent)"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=MODELS)
    ap.add_argument("--repeat", type=int, default=20)
    ap.add_argument("--budget-s", type=float, default=20.0, help="time budget per timing (min 3 runs)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--cache-frames", type=int, default=10, help="frames of the synthetic test cache (0: skip)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--merge", action="store_true", help="keep the other models' results already in --out")
    args = ap.parse_args(argv)

    import torch

    from xcalib.data.synth import write_site
    from xcalib.deploy.build import random_inputs
    from xcalib.deploy.ort_runtime import OnnxMatcher
    from xcalib.engine.evaluate import evaluate_matcher
    from xcalib.io.hdf5 import CacheReader

    torch.set_num_threads(args.threads)
    frame, a9_source = _a9_frame()
    rows, results = [], {}
    with tempfile.TemporaryDirectory(prefix="xcalib-bench-deploy-") as tmp:
        tmp = Path(tmp)
        cache = None
        if args.cache_frames > 0:
            write_site(tmp / "site", 0, 0, args.cache_frames, seed=0)
            cache = tmp / "site" / "test.h5"
        for name in args.models:
            m, weights = matcher_for(name, tmp)
            t0 = time.perf_counter()
            res = m.build("onnx", tmp / "onnx", site="bench")
            export_s = time.perf_counter() - t0
            om = OnnxMatcher(res.output_dir, threads=args.threads)
            inp = random_inputs(m.crop_config, 8, 12, seed=1)
            lat = {
                "K8_M12": {"torch": _p50(lambda: m.similarity(inp), args.repeat, args.budget_s),
                           "onnx": _p50(lambda: om.similarity(inp), args.repeat, args.budget_s)},
                "a9": {"torch": _p50(lambda: m.match_frame(frame, validate="off", geometry="off"), args.repeat,
                                     args.budget_s),  # the model path (not the off-site geometric consensus)
                       "onnx": _p50(lambda: om.match_frame(frame, validate="off", geometry="off"), args.repeat,
                                    args.budget_s)},
            }
            cfg = {k: m.config.get(k) for k in ("crop_size", "point_cloud_size", "embed_dim")}
            entry = {"weights": weights, "config": cfg, "parity": res.parity, "parity_ok": res.parity_ok,
                     "max_parity_error": res.max_parity_error, "export_s": export_s, "latency": lat}
            if cache is not None:
                with CacheReader(cache) as reader:
                    mt, _ = evaluate_matcher(m, reader)
                    mo, _ = evaluate_matcher(om, reader)
                entry["metrics"] = {
                    "torch": {k: getattr(mt, k) for k in ("top1", "top3", "mrr", "n_cameras_with_match")},
                    "onnx": {k: getattr(mo, k) for k in ("top1", "top3", "mrr", "n_cameras_with_match")}}
            results[name] = entry
            row = [name, f"{res.max_parity_error:.1e}", "yes" if res.parity_ok else "NO",
                   f"{lat['K8_M12']['torch']['p50_ms']:.1f}", f"{lat['K8_M12']['onnx']['p50_ms']:.1f}",
                   f"{lat['a9']['torch']['p50_ms']:.1f}", f"{lat['a9']['onnx']['p50_ms']:.1f}"]
            if cache is not None:
                t_, o_ = entry["metrics"]["torch"], entry["metrics"]["onnx"]
                row += [f"{100 * t_['top1']:.2f}/{100 * o_['top1']:.2f}", f"{100 * t_['top3']:.2f}/{100 * o_['top3']:.2f}",
                        f"{t_['mrr']:.4f}/{o_['mrr']:.4f}"]
            rows.append(row)
            print(" | ".join(row), flush=True)
    head = ["model", "parity max|d|", "parity ok", "K8M12 torch ms", "K8M12 ort ms", "A9 torch ms", "A9 ort ms"]
    if args.cache_frames > 0:
        head += ["Top-1 % torch/ort", "Top-3 % torch/ort", "MRR torch/ort"]
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    print("\n" + "  ".join(h.ljust(w) for h, w in zip(head, widths)))
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r, widths)))
    import onnxruntime

    from _provenance import provenance

    report = {"benchmark": "deploy", "provenance": provenance(argv), "a9_source": a9_source, "threads": args.threads,
              "cache": (f"synthetic roadside site seed 0 (the shipped 'synthetic' site), {args.cache_frames} held-out "
                        "test frames") if args.cache_frames else None,
              "gpu": "not measured (no GPU lent to this run)", "python": sys.version.split()[0],
              "torch": torch.__version__, "onnxruntime": onnxruntime.__version__, "machine": platform.machine(),
              "cpu_count": os.cpu_count(), "results": results}
    if args.merge and args.out.is_file():
        report["results"] = {**json.loads(args.out.read_text()).get("results", {}), **results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2))
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
