#!/usr/bin/env python
"""Reproduce the shipped weights (``src/xcalib/weights/<site>/``) and their figures.

Steps (each skipped when its output exists, so the script can be re-run after an interruption):

1. ``caches``: synthetic site A (the shipped "synthetic" site: ``sample_site(0, "roadside")``)
   with a training cache made of several independent traffic sequences, a validation cache
   and a held-out test cache; plus test caches of two other sites with different geometry
   (site B: roadside seed 3; site C: vehicle preset seed 5).
2. ``train``: every model with its shipped config (reduced widths where noted), Adam +
   warm-up + cosine, best by validation MRR; weights saved (fp16 storage) with their YAML.
3. ``eval``: Top-1 / Top-3 / MRR on A-test, B-test, C-test -> ``benchmarks/results/weights_eval.json``
   and the per-model ``manifest.json`` entry beside the weights.

Usage: ``python scripts/train_weights.py [--work /tmp/xcalib_weights] [--models fastmatch crlite ...]
[--steps caches train eval]``. CPU only is fine (``torch.set_num_threads(1)`` by default).
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
WEIGHTS = REPO / "src" / "xcalib" / "weights"
SITE = "synthetic"

# Shipped configs (merged over the reference-size defaults) and schedules.
VIT_SMALL = {"crop_size": 32, "point_cloud_size": 128, "embed_dim": 128,
             "vit": {"patch_size": 8, "embed_dim": 64, "depth": 2, "num_heads": 4, "mlp_ratio": 2.0}}
SHIPPED = {  # name: (config overrides, schedule; "stride" = use every n-th training frame)
    "fastmatch": ({}, dict(epochs=12, lr=3e-3, weight_decay=1e-4, max_3d=24, stride=1)),
    "crlite": ({"point_cloud_size": 128}, dict(epochs=5, lr=1e-3, max_3d=16, stride=2)),
    "crlite_vit_exp1": (VIT_SMALL, dict(epochs=12, lr=1e-3, max_3d=16, stride=1)),
    "crlite_vit_exp3": ({**VIT_SMALL, "token_len": 64}, dict(epochs=4, lr=1e-3, max_3d=16, stride=3)),
    "crlite_vit_exp4": ({**VIT_SMALL, "gnn": {"hidden_dim": 64}}, dict(epochs=12, lr=1e-3, max_3d=16, stride=1)),
    "crlite_2dpe": ({"point_cloud_size": 128}, dict(epochs=5, lr=1e-3, max_3d=16, stride=2)),
    "calibrefine": ({"point_cloud_size": 128, "num_blocks": [1, 1, 1, 1], "base_width": 16, "embed_dim": 128,
                     "token_len": 64, "dense": {"embed_dim": 128, "fusion_dim": 128, "hidden_dim": 64},
                     "pointnet2": [{"npoint": 64, "radius": 0.4, "nsample": 16, "mlp": [32, 32, 64]},
                                   {"npoint": 16, "radius": 1.0, "nsample": 16, "mlp": [64, 64, 128]},
                                   {"npoint": None, "mlp": [128, 256]}]},
                    dict(epochs=3, lr=1e-3, max_3d=12, stride=4)),
}
SITES = {"A": dict(seed=0, preset="roadside"), "B": dict(seed=3, preset="roadside", n_objects=20),
         "C": dict(seed=5, preset="vehicle", n_objects=20)}


def make_caches(work: Path, train_seqs: int = 8, frames_per_seq: int = 150, val_frames: int = 60,
                test_frames: int = 100) -> None:
    from xcalib.data.synth import iter_frames, sample_site, write_site
    from xcalib.io.hdf5 import CacheWriter

    for name, kw in SITES.items():
        d = work / f"site{name}"
        if not (d / "test.h5").exists():
            write_site(d, 0, val_frames if name == "A" else 0, test_frames, **kw)
            print(f"site {name}: test caches in {d}", flush=True)
    a = work / "siteA"
    if not (a / "train.h5").exists() or (a / "train.h5").stat().st_size < 1e6:
        kw = dict(SITES["A"])
        site = sample_site(kw.pop("seed"), kw.pop("preset"), **kw)
        tmp = a / "train_partial.h5"
        with CacheWriter(tmp, camera_names=[site.camera_name], lidar_name=site.lidar_name,
                         label_sensor=site.camera_name) as w:
            for s in range(train_seqs):  # independent traffic sequences (seeds disjoint from val/test)
                for k, f in enumerate(iter_frames(site, frames_per_seq, seed=100 + s)):
                    f.frame_key = f"{s:02d}{k:04d}"
                    w.add(f)
        tmp.replace(a / "train.h5")
        print(f"site A: train cache {train_seqs} x {frames_per_seq} frames", flush=True)


_SAMPLES: dict = {}


def _samples(name: str, cfg: dict, work: Path):
    """Training/validation crops, prepared once per crop setting and shared by the models."""
    from xcalib.data.crops import CropConfig
    from xcalib.engine.trainer import prepare_samples
    from xcalib.models import default_config, merge_config

    cc = CropConfig.from_config(merge_config(default_config(name), cfg))
    key = (cc.crop_size, cc.bbox_expansion, cc.keep_aspect, cc.normalize, cc.min_points)
    if key not in _SAMPLES:
        t0 = time.perf_counter()
        _SAMPLES[key] = tuple(prepare_samples(work / "siteA" / f"{s}.h5", cc)[0] for s in ("train", "val"))
        print(f"cropped {len(_SAMPLES[key][0])} train / {len(_SAMPLES[key][1])} val frames "
              f"in {time.perf_counter() - t0:.0f}s", flush=True)
    return _SAMPLES[key]


def train_model(name: str, work: Path) -> Path:
    import torch

    from xcalib.engine.matcher import Matcher
    from xcalib.engine.trainer import train

    cfg, sched = SHIPPED[name]
    sched = dict(sched)
    out = work / "runs" / name
    tr, va = _samples(name, cfg, work)
    tr = tr[::sched.pop("stride", 1)]
    t0 = time.perf_counter()
    best = train(name, tr, va, config=cfg, output_dir=out, warmup_epochs=1, frames_per_batch=4, seed=0,
                 device="cpu", progress=False, **sched)
    m = Matcher.from_pretrained(name, weights=best, device="cpu")
    paths = m.save_pretrained(WEIGHTS / SITE, dtype="float16")
    hist = json.loads((out / "history.json").read_text())
    info = {"train_wall_s": time.perf_counter() - t0, "epochs": len(hist), "config_overrides": cfg,
            "schedule": SHIPPED[name][1], "train_frames": len(tr), "best_val_mrr": max(h["val_mrr"] for h in hist),
            "parameters": m.model.num_parameters(), "weights_bytes": paths["weights"].stat().st_size}
    _update_manifest(name, {"training": info})
    print(f"{name}: trained in {info['train_wall_s']:.0f}s, best val MRR {info['best_val_mrr']:.4f}", flush=True)
    del torch
    return paths["weights"]


def _update_manifest(name: str, entry: dict) -> None:
    p = WEIGHTS / SITE / "manifest.json"
    man = json.loads(p.read_text()) if p.exists() else {"site": SITE, "made_by": "scripts/train_weights.py",
                                                         "models": {}}
    man["models"].setdefault(name, {}).update(entry)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(man, indent=1, sort_keys=True))


def evaluate_model(name: str, work: Path) -> dict:
    from xcalib.engine.evaluate import evaluate_matcher, report_entry
    from xcalib.engine.matcher import Matcher
    from xcalib.io.hdf5 import CacheReader

    m = Matcher.from_pretrained(name, site=SITE, device="cpu")
    res = {}
    for s in SITES:
        with CacheReader(work / f"site{s}" / "test.h5") as r:
            met, wall = evaluate_matcher(m, r)
        res[f"site{s}_test"] = report_entry(met, wall)
        print(f"{name} site {s}: top1 {met.top1:.4f} top3 {met.top3:.4f} mrr {met.mrr:.4f} "
              f"({met.n_cameras_with_match} rows, {met.n_frames} frames)", flush=True)
    _update_manifest(name, {"test": {k: {x: v[x] for x in ("top1", "top3", "mrr", "frame_top1", "n_frames",
                                                            "n_cameras_with_match")} for k, v in res.items()}})
    out = REPO / "benchmarks" / "results" / "weights_eval.json"
    allres = json.loads(out.read_text()) if out.exists() else {}
    allres[name] = res
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(allres, indent=1, sort_keys=True))
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/xcalib_weights"))
    ap.add_argument("--models", nargs="*", default=list(SHIPPED))
    ap.add_argument("--steps", nargs="*", default=["caches", "train", "eval"])
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    args.work.mkdir(parents=True, exist_ok=True)
    if "caches" in args.steps:
        make_caches(args.work)
    for name in args.models:
        if "train" in args.steps:
            train_model(name, args.work)
        if "eval" in args.steps:
            evaluate_model(name, args.work)


if __name__ == "__main__":
    main()
