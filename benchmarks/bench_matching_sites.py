#!/usr/bin/env python
"""Matching at sites the shipped weights never saw: Top-1 and precision/recall of the default
``matches``, per dataset, for the paths ``match`` has without site weights.

Datasets (each with its own truth, no labels used by any method):

* ``a9``: the 16 real A9 frames; truth = the matches of the all-frame calibration
  (``calibrate`` over the 16 frames, then ``derive_matches`` per frame).
* ``nuscenes``: the nuScenes sample, 6 cameras; truth = the info pickle's 2D-3D association.
* ``pandaset``: PandaSet 002, front camera, every ``--pandaset-every``-th frame; **synthetic 2D
  boxes** made by projecting the cuboids through each frame's ground-truth calibration
  (``xcalib.data.boxes2d``: occlusion, 1 px noise, 10 % missed, 5 % false boxes); 3D boxes = the
  cuboids holding 5+ LiDAR points.
* ``sustech``: SUSTechPOINTS example, the 3 frames with images x 3 cameras, 2D boxes made the
  same way (its calibration is approximate, hand-tuned).
* ``synthetic B`` / ``synthetic C``: the unseen synthetic sites of the shipped weights' manifest
  (``sample_site(3, "roadside", n_objects=20)``, ``sample_site(5, "vehicle")``), exact truth.

Rows (all with no site weights, "first frame": each frame alone):

* ``model generic`` / ``model synthetic``: the shipped weights' scores (``geometry="off"``);
* ``default``: ``Matcher.from_pretrained("fastmatch", site="generic").match_frame(frame)`` as a
  user gets it (out-of-domain scores -> geometric consensus; ``source`` counts in the JSON);
* ``geometry, K given`` / ``geometry, K searched``: consensus with the frame's intrinsics / none.

After bootstrap (``--bootstrap-steps``, 0: none), per dataset with frames to bootstrap on:
``bootstrap`` (no install) on the first frames, then on the frames it never saw: ``model`` (the
adapted model alone), ``geometry`` (the bootstrap pose alone, ``derive_matches``), ``fused``
(``use_calibration=True``) and ``default`` (``match`` at the bootstrapped site, which follows the
``site_default`` bootstrap chose), plus bootstrap's own held-out check (``oneshot.heldout``).
A9: frames 0-11 / 12-15; PandaSet: all 30 frames, first 2/3 / last 1/3; synthetic B: 12 more
frames / the 6 of the first-frame rows' kind; SUSTech: front camera, 2 frames / 1 (the
calibrator is expected to refuse so few); nuScenes: one sample, nothing to bootstrap on.

Top-1: share of 2D boxes with a true partner whose best-scored 3D box is it. Precision/recall:
of the ``matches`` list at the default settings. Prints one table (first frame and after
bootstrap) and writes benchmarks/results/matching_sites.json.

    OMP_NUM_THREADS=1 python benchmarks/bench_matching_sites.py [--datasets a9 nuscenes ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("XCALIB_SHARED_DATA", REPO.parent / "shared" / "data"))
OUT = REPO / "benchmarks" / "results" / "matching_sites.json"


# ----------------------------------------------------------------------------------- datasets
def a9():
    from xcalib.calib.api import calibrate
    from xcalib.calib.matching import derive_matches
    from xcalib.io.frames import read_frames

    seq = read_frames(SHARED / "a9_sample")
    frames = [dataclasses.replace(seq[i], intrinsics=seq.intrinsics) for i in range(len(seq))]
    cal = calibrate(frames, seq.intrinsics)
    if not cal.success:
        raise RuntimeError(f"A9 all-frame calibration failed: {cal.message}")
    return [(f, {int(a): int(b) for a, b in derive_matches(f, cal).pairs}) for f in frames]


def _truth(mm) -> dict:
    i, j = np.nonzero(np.asarray(mm))
    return {int(a): int(b) for a, b in zip(i, j)}


def nuscenes():
    from xcalib.formats.mmdet3d import mmdet3d_frames

    pkl = next((SHARED / "nuscenes" / "mmdet3d_demo").glob("*.pkl"))
    return [(f, _truth(f.match_matrix)) for f in mmdet3d_frames(pkl)]


def synthetic(seed: int, preset: str, n: int, **kw):
    from xcalib.data.synth import generate_frames, sample_site

    return [(f, _truth(f.match_matrix)) for f in generate_frames(sample_site(seed, preset, **kw), n, seed=900)]


def projected_boxes_frame(frame, seed: int, min_points: int = 5):
    """(frame, truth) with synthetic 2D boxes (``xcalib.data.boxes2d``: the 3D boxes projected with
    the frame's ground-truth calibration at the camera time, occlusion, 1 px noise, 10 % missed,
    5 % false); the 3D boxes are those holding ``min_points``+ LiDAR points (what a detector sees)."""
    from xcalib.data.boxes2d import synthetic_2d_boxes
    from xcalib.geometry.boxes import as_box7, points_in_boxes

    f = synthetic_2d_boxes(frame, seed=seed)
    keep = np.flatnonzero(points_in_boxes(f.point_cloud[:, :3], as_box7(f.bboxes_3d)).sum(1) >= min_points)
    meta = dict(f.meta or {})
    if "box7" in meta:
        meta["box7"] = np.asarray(meta["box7"])[keep]
    f = dataclasses.replace(f, bboxes_3d=np.asarray(f.bboxes_3d)[keep], match_matrix=f.match_matrix[:, keep],
                            meta=meta)
    return f, _truth(f.match_matrix)


def pandaset(every: int):
    from xcalib.formats.pandaset import PandaSetFrames

    seq = PandaSetFrames(SHARED / "pandaset_002")
    return [projected_boxes_frame(seq[i], seed=i) for i in range(0, len(seq), every)]


def sustech():
    from xcalib.formats.sustech import SustechFrames

    out = []
    for cam in ("front", "left", "right"):
        seq = SustechFrames(SHARED / "sustech_example", camera=cam)
        for i in range(len(seq)):
            f = seq[i]
            if f.image.size:
                out.append(projected_boxes_frame(f, seed=100 + len(out)))
    return out


# ----------------------------------------------------------------------------------- scoring
def score(result, frame, truth: dict) -> dict:
    full = result.full_similarity(frame.num_2d, frame.num_3d, fill=-np.inf)
    top1 = [bool(np.isfinite(full[i]).any() and full[i].max() > -np.inf and full[i].argmax() == j
                 and (result.source != "geometry" or full[i].max() > 0)) for i, j in truth.items()]
    pred = {(int(a), int(b)) for a, b in result.as_pairs()}
    true = set(truth.items())
    return {"top1_hits": int(sum(top1)), "rows": len(truth), "pred": len(pred), "correct": len(pred & true),
            "source": result.source}


def summarise(recs: list[dict]) -> dict:
    rows = sum(r["rows"] for r in recs)
    pred = sum(r["pred"] for r in recs)
    correct = sum(r["correct"] for r in recs)
    src: dict[str, int] = {}
    for r in recs:
        src[r["source"]] = src.get(r["source"], 0) + 1
    return {"top1": sum(r["top1_hits"] for r in recs) / max(rows, 1), "precision": correct / pred if pred else None,
            "recall": correct / max(rows, 1), "frames": len(recs), "rows_with_partner": rows, "matches": pred,
            "sources": src, "seconds_per_frame": float(np.mean([r["s"] for r in recs])) if recs else None}


def variants(generic, synthetic_m):
    return {
        "model generic": lambda f: generic.match_frame(f, validate="off", geometry="off"),
        "model synthetic": lambda f: synthetic_m.match_frame(f, validate="off", geometry="off"),
        "default (generic weights)": lambda f: generic.match_frame(f, validate="off"),
        "geometry, K given": lambda f: generic.match_frame(f, validate="off", geometry="on"),
        "geometry, K searched": lambda f: generic.match(*f.inputs(), validate="off", geometry="on",
                                                        box7=(f.meta or {}).get("box7")),
    }


def bootstrap_sets(args) -> dict:
    """Per dataset: (frames to bootstrap on, [(frame, truth)] to evaluate on, note) or a reason
    why no bootstrap row can be measured (a string)."""
    def split(data, fit):
        return [f for f, _ in data[:fit]], data[fit:]

    out = {}
    if "a9" in args.datasets:
        d = a9()
        out["a9"] = split(d, args.bootstrap_fit) + (f"bootstrap on frames 0-{args.bootstrap_fit - 1}, "
                                                    f"evaluated on {len(d) - args.bootstrap_fit}",)
    if "pandaset" in args.datasets:
        from xcalib.formats.pandaset import PandaSetFrames

        seq = PandaSetFrames(SHARED / "pandaset_002")
        d = [projected_boxes_frame(seq[i], seed=i) for i in range(len(seq))]
        fit = int(round(len(d) * 2 / 3))
        out["pandaset"] = split(d, fit) + (f"bootstrap on frames 0-{fit - 1}, evaluated on {len(d) - fit}",)
    if "sustech" in args.datasets:
        d = sustech()[:3]  # the front camera's 3 frames (sustech() lists front, left, right)
        out["sustech"] = split(d, 2) + ("front camera: bootstrap on 2 frames, evaluated on 1 (3 frames with images)",)
    if "nuscenes" in args.datasets:
        out["nuscenes"] = "n/a: one sample (one frame per camera), nothing to bootstrap on"
    if "synthetic B" in args.datasets:
        d = synthetic(3, "roadside", args.bootstrap_fit + args.synthetic_frames, n_objects=20)
        out["synthetic B"] = split(d, args.bootstrap_fit) + (
            f"bootstrap on {args.bootstrap_fit} frames, evaluated on {args.synthetic_frames}",)
    if "synthetic C" in args.datasets:
        out["synthetic C"] = "not measured: <= 2 objects per frame (the model path serves it, see first frame)"
    return out


def after_bootstrap(name: str, fit_frames, data, steps: int, note: str) -> dict:
    """After ``bootstrap`` on ``fit_frames`` (no install), on ``data`` (frames it never saw): the
    adapted model alone, the bootstrap pose alone (``derive_matches``), the model fused with the
    pose (``use_calibration=True``) and ``match``'s default at the bootstrapped site (the
    ``site_default`` bootstrap chose), against each dataset's truth (for A9 the all-frame
    calibration's matches: the pose-only figure is partly circular there)."""
    from xcalib.calib.matching import derive_matches
    from xcalib.oneshot.bootstrap import bootstrap
    from xcalib.types import MatchResult

    intr = fit_frames[0].intrinsics
    t0 = time.perf_counter()
    res = bootstrap(fit_frames, intr, f"bench_{name}", steps=steps, install=False, device="cpu", seed=0)
    boot_s = time.perf_counter() - t0
    m, cal = res.matcher, res.calibration

    def pose_only(f):
        pl = derive_matches(f, cal)
        k2, k3 = np.arange(f.num_2d), np.arange(f.num_3d)
        return MatchResult(similarity=pl.iou.astype(np.float32), top_indices=pl.iou.argmax(1) if pl.iou.size else
                           np.zeros(0, np.int64), matches=[(int(a), int(b), 1.0) for a, b in pl.pairs],
                           kept_2d_indices=k2, kept_3d_indices=k3, source="geometry")

    rows = {"model": lambda f: m.match_frame(f, validate="off", use_calibration=False, geometry="off"),
            "geometry": pose_only,
            "fused": lambda f: m.match_frame(f, validate="off", use_calibration=True),
            "default": lambda f: m.match_frame(f, validate="off")}
    h = res.heldout
    out = {"note": note, "fit_frames": len(fit_frames), "eval_frames": len(data), "steps": steps,
           "bootstrap_s": boot_s, "site_default": None if res.site_default is None else res.site_default.source,
           "site_threshold": None if res.threshold is None else res.threshold.threshold,
           "heldout_check": None if h is None else {"frames": h.n_frames, "top1": h.top1,
                                                     "top1_independent": h.top1_independent,
                                                     "label_agreement": h.label_agreement, "verified": h.verified,
                                                     "reported_top1": h.reported_top1, "interval": list(h.interval),
                                                     "message": h.message}}
    for row, fn in rows.items():
        recs = []
        for f, truth in data:
            t1 = time.perf_counter()
            r = fn(f)
            recs.append({**score(r, f, truth), "s": time.perf_counter() - t1})
        out[row] = summarise(recs)
        s = out[row]
        print(f"{name:12s} after bootstrap  {row:9s} Top-1 {s['top1']:.3f}  P {s['precision'] or 0:.3f}  "
              f"R {s['recall']:.3f}  ({s['frames']} frames)", flush=True)
    print(f"{name:12s} after bootstrap: site default {out['site_default']}, held-out check: "
          f"{'-' if h is None else h.message}", flush=True)
    return out


def cell(s: dict | None) -> str:
    if not s or "top1" not in s:
        return "-"
    p = "-" if s["precision"] is None else f"{s['precision']:.2f}"
    return f"{s['top1']:.2f} / {p} / {s['recall']:.2f}"


FIRST_COLUMNS = {"model (shipped)": "model generic", "geometry (consensus)": "geometry, K given",
                 "default": "default (generic weights)"}
AFTER_COLUMNS = ("model", "geometry", "fused", "default")


def print_table(table: dict) -> None:
    """One table: first frame without site weights, then after bootstrap (held-out frames)."""
    head = ([f"first frame: {c}" for c in FIRST_COLUMNS] + [f"after bootstrap: {c}" for c in AFTER_COLUMNS]
            + ["held-out check"])
    print("\n| dataset | " + " | ".join(head) + " |\n|---|" + "---|" * len(head))
    for d, rows in table.items():
        if "skipped" in rows:
            print(f"| {d} | skipped: {rows['skipped'][:60]} |")
            continue
        first = [cell(rows.get(v)) for v in FIRST_COLUMNS.values()]
        after = rows.get("after bootstrap")
        if isinstance(after, dict) and "model" in after:
            h = after["heldout_check"]
            check = ("none held out (too few frames)" if h is None else f"{h['reported_top1']:.2f} ({h['frames']} frames, checked)" if h["verified"]
                     else f"not reported ({h['frames']} frames)")
            rest = [cell(after[c]) for c in AFTER_COLUMNS] + [check]
        else:
            why = after.get("failed") if isinstance(after, dict) else (after or "not run")
            rest = [str(why)[:90]] + [""] * len(AFTER_COLUMNS)
        print(f"| {d} | " + " | ".join(first + rest) + " |")
    print("cells: Top-1 / precision / recall of the default matches; first frame: every frame alone, no site "
          "weights; after bootstrap: frames the bootstrap did not see (see each dataset's note in the JSON)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+",
                    default=["a9", "nuscenes", "pandaset", "sustech", "synthetic B", "synthetic C"])
    ap.add_argument("--pandaset-every", type=int, default=3)
    ap.add_argument("--synthetic-frames", type=int, default=6)
    ap.add_argument("--bootstrap-fit", type=int, default=12,
                    help="A9 and synthetic B: bootstrap on the first N frames (PandaSet: the first 2/3)")
    ap.add_argument("--bootstrap-steps", type=int, default=600, help="0: no bootstrap rows")
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    logging.getLogger("xcalib").setLevel(logging.ERROR)  # the out-of-domain warning, once per matcher
    from xcalib.engine.matcher import Matcher

    generic = Matcher.from_pretrained("fastmatch", site="generic", device="cpu")
    synth_m = Matcher.from_pretrained("fastmatch", site="synthetic", device="cpu")
    loaders = {"a9": a9, "nuscenes": nuscenes, "pandaset": lambda: pandaset(args.pandaset_every),
               "sustech": sustech,
               "synthetic B": lambda: synthetic(3, "roadside", args.synthetic_frames, n_objects=20),
               "synthetic C": lambda: synthetic(5, "vehicle", args.synthetic_frames)}
    table: dict[str, dict] = {}
    for name in args.datasets:
        try:
            data = loaders[name]()
        except (ImportError, FileNotFoundError, StopIteration, RuntimeError) as exc:
            table[name] = {"skipped": f"{type(exc).__name__}: {exc}"}
            print(f"{name}: skipped ({exc})", flush=True)
            continue
        table[name] = {}
        for vname, fn in variants(generic, synth_m).items():
            recs = []
            for f, truth in data:
                t0 = time.perf_counter()
                r = fn(f)
                recs.append({**score(r, f, truth), "s": time.perf_counter() - t0})
            table[name][vname] = summarise(recs)
            s = table[name][vname]
            prec = "-" if s["precision"] is None else f"{s['precision']:.3f}"
            print(f"{name:12s} {vname:28s} Top-1 {s['top1']:.3f}  P {prec}  R {s['recall']:.3f}  "
                  f"({s['frames']} frames, {s['rows_with_partner']} boxes with a partner, {s['sources']}, "
                  f"{s['seconds_per_frame']:.2f} s/frame)", flush=True)
    if args.bootstrap_steps > 0:
        for name, spec in bootstrap_sets(args).items():
            if name not in table or "skipped" in table[name]:
                continue
            if isinstance(spec, str):
                table[name]["after bootstrap"] = spec
                continue
            try:
                table[name]["after bootstrap"] = after_bootstrap(name, spec[0], spec[1], args.bootstrap_steps, spec[2])
            except Exception as exc:  # noqa: BLE001 - a refused bootstrap is a result, not a crash
                table[name]["after bootstrap"] = {"failed": f"{type(exc).__name__}: {exc}", "note": spec[2]}
                print(f"{name}: after bootstrap: failed ({exc})", flush=True)
    print_table(table)
    from _provenance import provenance

    report = {"benchmark": "matching_sites", "provenance": provenance(argv),
              "cells": "Top-1, precision and recall of the default matches",
              "loadavg": list(os.getloadavg()), "results": table}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(report, indent=1))
    tmp.replace(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
