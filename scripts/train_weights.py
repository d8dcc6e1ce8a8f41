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

Separate step ``generic`` (not in the default steps; needs the site A/B/C test caches of
``caches``): the ``site="generic"`` fastmatch weights, trained on many randomised sites
(domain randomisation) and tested on sites A, B and C, none of which it saw.

* caches: ``--generic-sites`` (default 240) training sites, seeds 7000, 7001, ... and 4
  validation sites, seeds 7600..7603 (disjoint from A/B/C and from the seeds of tests and
  benchmarks), each 16 rendered frames (4 traffic sequences x frames 0, 12, 24, 36) in
  ``<work>/generic/{train,val}/site<seed>.h5``. A site draws its preset (35% ``vehicle``,
  else ``roadside``), image size (1920 x 1200 or 1080, scaled by 1, 0.75 or 0.5, focal range
  scaled with it) and everything else its preset randomises (camera height, yaw, pitch,
  roll, LiDAR mount, lanes, object counts, light) from its seed (:func:`generic_site`).
* training: fastmatch with its default config, ``--generic-epochs`` (default 12) epochs of
  Adam (lr 3e-3, weight decay 1e-4, max_3d 24), best by MRR on the validation sites; saved
  (fp16) to ``src/xcalib/weights/generic/`` with its ``manifest.json``.
* eval: Top-1 / Top-3 / MRR of the generic and the shipped ``synthetic`` fastmatch on the A,
  B and C test caches -> ``benchmarks/results/weights_generic.json``.

``python scripts/train_weights.py --steps generic [--generic-sites 240] [--generic-epochs 12]``
(on one CPU core: about 15 min of caches, 3 min of cropping, 10 min of training, 3 min of evaluation).
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
                    dict(epochs=8, lr=1e-3, max_3d=12, stride=1)),
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
            write_site(d, 0, val_frames if name == "A" else 0, test_frames, overwrite=True, **kw)
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
    from xcalib.engine.trainer import XCALIB_RECIPE, train

    cfg, sched = SHIPPED[name]
    sched = dict(sched)
    out = work / "runs" / name
    tr, va = _samples(name, cfg, work)
    tr = tr[::sched.pop("stride", 1)]
    t0 = time.perf_counter()
    best = train(name, tr, va, config=cfg, output_dir=out, frames_per_batch=4, seed=0,
                 device="cpu", progress=False, **{**XCALIB_RECIPE.kwargs(warmup_epochs=1), **sched})
    m = Matcher.from_pretrained(name, weights=best, device="cpu")
    paths = m.save_pretrained(WEIGHTS / SITE, dtype="float16", overwrite=True)
    hist = json.loads((out / "history.json").read_text())
    info = {"train_wall_s": time.perf_counter() - t0, "epochs": len(hist), "config_overrides": cfg,
            "schedule": SHIPPED[name][1], "train_frames": len(tr), "best_val_mrr": max(h["val_mrr"] for h in hist),
            "parameters": m.model.num_parameters(), "weights_bytes": paths["weights"].stat().st_size}
    _update_manifest(name, {"training": info})
    print(f"{name}: trained in {info['train_wall_s']:.0f}s, best val MRR {info['best_val_mrr']:.4f}", flush=True)
    del torch
    return paths["weights"]


def _update_manifest(name: str, entry: dict, site: str = SITE) -> None:
    p = WEIGHTS / site / "manifest.json"
    man = json.loads(p.read_text()) if p.exists() else {"site": site, "made_by": "scripts/train_weights.py",
                                                         "models": {}}
    man["models"].setdefault(name, {}).update(entry)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(man, indent=1, sort_keys=True))


MANIFEST_METRICS = ("top1", "top3", "mrr", "frame_top1", "n_frames", "n_cameras_with_match")


def _eval_sites(name: str, site: str, work: Path, label: str) -> dict:
    """Report entries of weights ``site`` of model ``name`` on the A/B/C test caches under ``work``."""
    from xcalib.engine.evaluate import evaluate_matcher, report_entry
    from xcalib.engine.matcher import Matcher
    from xcalib.io.hdf5 import CacheReader

    m = Matcher.from_pretrained(name, site=site, device="cpu")
    res = {}
    for s in SITES:
        with CacheReader(work / f"site{s}" / "test.h5") as r:
            met, wall = evaluate_matcher(m, r)
        res[f"site{s}_test"] = report_entry(met, wall)
        print(f"{label} site {s}: top1 {met.top1:.4f} top3 {met.top3:.4f} mrr {met.mrr:.4f} "
              f"({met.n_cameras_with_match} rows, {met.n_frames} frames)", flush=True)
    return res


def _manifest_metrics(res: dict) -> dict:
    return {k: {x: v[x] for x in MANIFEST_METRICS} for k, v in res.items()}


def evaluate_model(name: str, work: Path) -> dict:
    res = _eval_sites(name, SITE, work, name)
    _update_manifest(name, {"test": _manifest_metrics(res)})
    out = REPO / "benchmarks" / "results" / "weights_eval.json"
    allres = json.loads(out.read_text()) if out.exists() else {}
    allres[name] = res
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(allres, indent=1, sort_keys=True))
    return res


# ---------------------------------------------------------------- generic (domain-randomised) weights
GENERIC = "generic"
GENERIC_SCHEDULE = dict(lr=3e-3, weight_decay=1e-4, max_3d=24)
GENERIC_TRAIN_SEED0, GENERIC_VAL_SEEDS = 7000, (7600, 7601, 7602, 7603)
GENERIC_SEQUENCES, GENERIC_STARTS = (50, 51, 52, 53), (0, 12, 24, 36)


def generic_site(seed: int):
    """A randomised site of the generic training set: preset, image size and lens drawn from ``seed``."""
    import numpy as np

    from xcalib.data.synth import sample_site

    r = np.random.default_rng([seed, 4242])
    preset = "vehicle" if r.uniform() < 0.35 else "roadside"
    s = float(r.choice([1.0, 1.0, 0.75, 0.5]))
    h = 1200 if r.uniform() < 0.6 else 1080
    lo, hi = (1000.0, 1800.0) if preset == "vehicle" else (1000.0, 2500.0)
    return sample_site(seed, preset, width=int(round(1920 * s)), height=int(round(h * s)), focal_px=(lo * s, hi * s))


def _generic_cache(path: Path, seed: int) -> None:
    from xcalib.data.synth import iter_frames
    from xcalib.io.hdf5 import CacheWriter

    if path.exists():
        return
    site = generic_site(seed)
    with CacheWriter(path, camera_names=[site.camera_name], lidar_name=site.lidar_name,
                     label_sensor=site.camera_name) as w:
        for q, seq in enumerate(GENERIC_SEQUENCES):
            for st in GENERIC_STARTS:
                for f in iter_frames(site, 1, seed=seq, start=st):
                    f.frame_key = f"{q}{st:04d}"
                    w.add(f)


def generic_step(work: Path, n_sites: int = 240, epochs: int = 12) -> dict:
    """Caches, training and evaluation of the ``generic`` fastmatch (see the module docstring)."""
    from xcalib.data.crops import CropConfig
    from xcalib.engine.matcher import Matcher
    from xcalib.engine.trainer import XCALIB_RECIPE, prepare_samples, train
    from xcalib.models import default_config

    g = work / "generic"
    seeds = {"train": [GENERIC_TRAIN_SEED0 + i for i in range(n_sites)], "val": list(GENERIC_VAL_SEEDS)}
    t0 = time.perf_counter()
    for split, ss in seeds.items():
        for i, seed in enumerate(ss):
            _generic_cache(g / split / f"site{seed}.h5", seed)
            if (i + 1) % 20 == 0 or i + 1 == len(ss):
                print(f"generic {split}: {i + 1}/{len(ss)} sites ({time.perf_counter() - t0:.0f}s)", flush=True)
    best = g / "runs" / "fastmatch" / "best.pth"
    out = WEIGHTS / GENERIC
    if not any((out / f"fastmatch{s}").exists() for s in (".pt", ".pth")):
        cc = CropConfig.from_config(default_config("fastmatch"))
        tr, va = ([s for seed in ss for s in prepare_samples(g / split / f"site{seed}.h5", cc)[0]]
                  for split, ss in seeds.items())
        print(f"generic: cropped {len(tr)} train / {len(va)} val frames", flush=True)
        t0 = time.perf_counter()
        best = train("fastmatch", tr, va, config={}, output_dir=best.parent, frames_per_batch=4, seed=0, device="cpu",
                     progress=False, **{**XCALIB_RECIPE.kwargs(epochs=epochs, warmup_epochs=1), **GENERIC_SCHEDULE})
        m = Matcher.from_pretrained("fastmatch", weights=best, device="cpu")
        paths = m.save_pretrained(out, dtype="float16", overwrite=True)
        hist = json.loads((best.parent / "history.json").read_text())
        info = {"train_wall_s": time.perf_counter() - t0, "epochs": len(hist), "config_overrides": {},
                "schedule": {"epochs": epochs, **GENERIC_SCHEDULE}, "train_frames": len(tr),
                "train_sites": n_sites, "train_site_seeds": [seeds["train"][0], seeds["train"][-1]],
                "val_site_seeds": seeds["val"], "val_frames": len(va),
                "best_val_mrr": max(h["val_mrr"] for h in hist), "parameters": m.model.num_parameters(),
                "weights_bytes": paths["weights"].stat().st_size}
        _update_manifest("fastmatch", {"training": info}, site=GENERIC)
        print(f"generic fastmatch: trained in {info['train_wall_s']:.0f}s, best val MRR "
              f"{info['best_val_mrr']:.4f}", flush=True)
    res = {site: _eval_sites("fastmatch", site, work, f"fastmatch[{site}]") for site in (GENERIC, SITE)}
    _update_manifest("fastmatch", {"test": _manifest_metrics(res[GENERIC])}, site=GENERIC)
    man = json.loads((WEIGHTS / GENERIC / "manifest.json").read_text())
    doc = {"model": "fastmatch", "made_by": "scripts/train_weights.py --steps generic",
           "training": man["models"]["fastmatch"].get("training", {}), "test_sites": SITES,
           "results": {site: _manifest_metrics(r) for site, r in res.items()}}
    p = REPO / "benchmarks" / "results" / "weights_generic.json"
    p.parent.mkdir(parents=True, exist_ok=True)
    old = json.loads(p.read_text()) if p.exists() else {}  # keeps entries other runs added
    p.write_text(json.dumps({**old, **doc}, indent=1, sort_keys=True))
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/xcalib_weights"))
    ap.add_argument("--models", nargs="*", default=list(SHIPPED))
    ap.add_argument("--steps", nargs="*", default=["caches", "train", "eval"],
                    help="caches, train, eval, generic, checksums (sha256 sidecars of the shipped weights)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--generic-sites", type=int, default=240, help="training sites of the generic step")
    ap.add_argument("--generic-epochs", type=int, default=12, help="training epochs of the generic step")
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
    if "generic" in args.steps:
        generic_step(args.work, args.generic_sites, args.generic_epochs)
    if "checksums" in args.steps:
        write_checksums()


def write_checksums() -> None:
    """``<model>.sha256`` beside every shipped weights file (save_pretrained writes them for new
    weights; this step covers files written before checksums existed). Checked on every load."""
    from xcalib.engine.checkpoint import WEIGHT_SUFFIXES, write_checksum

    for p in sorted(q for s in WEIGHT_SUFFIXES for q in WEIGHTS.glob(f"*/*{s}")):
        print(f"{write_checksum(p)}: {p.with_suffix('.sha256').read_text().split()[0][:16]}...", flush=True)


if __name__ == "__main__":
    main()
