"""Calibration from a real camera detector's boxes (issue 25): does xcalib deliver on real detections?

The 2D boxes come from ``../shared/data/real_detections`` (YOLOX-Nano, COCO; README there): one
JSON per image, every detection with score >= 0.05. Here: the traffic classes (person, bicycle,
car, motorcycle, bus, truck, train) at a score threshold. The 3D boxes are the datasets' own.

Cases:

* A9 sample (16 frames; no ground truth): the reference is the pose the *labelled* 2D boxes give
  (all 16 frames, defaults). Detector boxes at input 1280 with score >= 0.3 and >= 0.5, and at
  input 416 with score >= 0.3.
* PandaSet 002 front camera (frames 00-29; per-frame ground truth ``T_cam_lidar``): detector boxes
  (1280, score >= 0.3), and the projected-cuboid 2D boxes ``bench_selfcal.py`` uses
  (``xcalib.data.boxes2d.synthetic_2d_boxes``, one seed per frame). Error: median over the frames
  of the gap to each frame's truth.

Columns: success, refusal code, pairs, the error (of the refused pose too, from
``diagnostics.refused_T``), the reported 1-sigma (norm over the axes), whether the error lies
within the reported 2-sigma, and what the box observation model fitted (``diagnostics.box_fit``).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibration_detections.py [--only a9|pandaset] [--subsets 20]

``--subsets N`` adds N random A9 subsets each: labelled boxes, 8 frames, and detector boxes (1280,
score >= 0.3), 12 frames, against the labelled all-frame pose (issue 25's "Done when").

Prints a table and writes ``benchmarks/results/calibration_detections.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibration import machine_info, write_result  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("XCALIB_SHARED_DATA", REPO.parent / "shared" / "data"))
DETS = SHARED / "real_detections"
OUT = REPO / "benchmarks" / "results" / "calibration_detections.json"
TRAFFIC = ("person", "bicycle", "car", "motorcycle", "bus", "truck", "train")


def load_detections(path: Path, score_min: float, classes=TRAFFIC) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(boxes [K,4] px, scores [K], class names) of one detection JSON, filtered by class and score."""
    d = json.loads(path.read_text())
    keep = [x for x in d["detections"] if x["class"] in classes and float(x["score"]) >= score_min]
    boxes = np.array([[x["x1"], x["y1"], x["x2"], x["y2"]] for x in keep], dtype=np.float32).reshape(-1, 4)
    return boxes, np.array([float(x["score"]) for x in keep]), [x["class"] for x in keep]


def with_detections(frame, path: Path, score_min: float):
    """``frame`` with its 2D boxes replaced by the detector's (no match matrix: none is known)."""
    boxes, scores, classes = load_detections(path, score_min)
    meta = {**(frame.meta or {}), "scores_2d": scores, "classes_2d": classes}
    return dataclasses.replace(frame, bboxes_2d=boxes, match_matrix=None, meta=meta)


def _norms(res) -> tuple[float, float]:
    return float(np.linalg.norm(res.rotation_std_deg)), float(np.linalg.norm(res.translation_std_m))


def _pose_of(res):
    from xcalib.calib.pose import Pose

    T = res.extrinsics if res.rotation is not None else getattr(res.diagnostics, "refused_T", None)
    return None if T is None else Pose.parse(np.asarray(T))


ADVICE = re.compile(r"(refine_intrinsics|time_offset)='([a-z+]+)'")


def advice_of(message: str) -> dict:
    """The options a refusal's message advises (``refine_intrinsics='focal'`` etc.; the last wins)."""
    return {k: v for k, v in ADVICE.findall(message or "")}


def follow_advice(frames, intr, truths, rec: dict, steps: int = 3) -> list[dict]:
    """Follow a refusal's advice up to ``steps`` times (issue 25 item 2): each step calibrates
    again with the advised options added. A loop -- the same refusal under options already tried
    -- is marked ``loop``."""
    from xcalib.calib.config import CalibConfig

    chain, opts, seen = [], {}, {(rec["refusal"], ())}
    while not rec["success"] and len(chain) < steps:
        adv = advice_of(rec["message"])
        new = {k: v for k, v in adv.items() if opts.get(k) != v}
        if not new:
            break
        opts = {**opts, **new}
        rec = run_case(f"  advice {opts}", frames, intr, truths, CalibConfig(**opts))
        key = (rec["refusal"], tuple(sorted(opts.items())))
        rec["loop"] = bool(not rec["success"] and any(r == rec["refusal"] for r, _ in seen))
        seen.add(key)
        chain.append({k: v for k, v in rec.items() if k != "T"})
    return chain


def run_case(name: str, frames, intr, truths, config=None) -> dict:
    """Calibrate ``frames``; error against ``truths`` (one pose, or one per frame: median)."""
    from xcalib.calib.api import calibrate

    t0 = time.perf_counter()
    res = calibrate(frames, intr, config)
    diag = res.diagnostics
    rec = {"case": name, "success": bool(res.success), "refusal": diag.refusal, "message": res.message,
           "time_s": round(time.perf_counter() - t0, 2), "n_pairs": int(res.n_pairs), "frames": len(frames),
           "n_2d": int(sum(len(f.bboxes_2d) for f in frames)),
           "box_fit": getattr(diag, "box_fit", None), "box_model": diag.box_model}
    pose = _pose_of(res)
    if pose is not None:
        rec["T"] = pose.T.tolist()
        rec["sigma_deg"], rec["sigma_m"] = _norms(res)
    if pose is not None and truths is not None:
        errs = np.array([pose.error(t) for t in truths])
        rec["err_deg"], rec["err_m"] = float(np.median(errs[:, 0])), float(np.median(errs[:, 1]))
        rec["covered_2sigma"] = bool(rec["err_deg"] <= 2 * rec["sigma_deg"] and rec["err_m"] <= 2 * rec["sigma_m"])
    return rec


def a9_folders(root: Path) -> dict[str, str]:
    """frame_key -> the frame's folder name (``manifest.json``: the keys are not the folder numbers);
    the detection JSON of a frame is named after its folder (README of ``real_detections``)."""
    man = json.loads((root / "manifest.json").read_text())
    return {str(e["frame_key"]): Path(e["detections"]).parent.name for e in man["frames"]}


def a9_cases() -> list[dict]:
    root = SHARED / "a9_sample"
    if not root.exists() or not DETS.exists():
        return [{"case": "a9", "skipped": f"data not found: {root} / {DETS}"}]
    from xcalib.calib.pose import Pose
    from xcalib.io.frames import read_frames

    seq = read_frames(root)
    frames = [seq[i] for i in range(len(seq))]
    intr = seq.intrinsics
    ref = run_case("A9 labelled boxes (reference)", frames, intr, None)
    out = [ref]
    ref_pose = Pose.parse(np.asarray(ref["T"])) if "T" in ref else None  # refused: its refused_T
    folder = a9_folders(root)
    for size, smin in (("1280", 0.3), ("1280", 0.5), ("416", 0.3)):
        det = [with_detections(f, DETS / f"yolox_nano_{size}" / "a9" / f"{folder[f.frame_key]}.json", smin)
               for f in frames]
        rec = run_case(f"A9 detector {size} score>={smin}", det, intr, None if ref_pose is None else [ref_pose])
        rec["advice_chain"] = follow_advice(det, intr, None if ref_pose is None else [ref_pose], rec)
        out.append(rec)
    return out


def a9_subsets(n_random: int) -> list[dict]:
    """Random subsets (``bench_calibration_a9.subsets``, same seeds): labelled boxes 8 frames and
    detector boxes (1280, score >= 0.3) 12 frames, against the labelled all-frame pose. 'wrong':
    a success > 1 deg or > 0.5 m off; coverage: the gap within the reported 2-sigma."""
    root = SHARED / "a9_sample"
    if not root.exists() or not DETS.exists():
        return [{"case": "a9 subsets", "skipped": f"data not found: {root} / {DETS}"}]
    from bench_calibration_a9 import subsets

    from xcalib.calib.pose import Pose
    from xcalib.io.frames import read_frames

    seq = read_frames(root)
    frames = [seq[i] for i in range(len(seq))]
    intr = seq.intrinsics
    ref = run_case("ref", frames, intr, None)
    ref_pose = Pose.parse(np.asarray(ref["T"]))
    folder = a9_folders(root)
    det = [with_detections(f, DETS / "yolox_nano_1280" / "a9" / f"{folder[f.frame_key]}.json", 0.3) for f in frames]
    sets = subsets(len(frames), n_random)
    rows = []
    for name, fr, key in (("A9 labelled, random 8 frames", frames, "random 8"),
                          ("A9 detector 1280>=0.3, random 12 frames", det, "random 12")):
        recs = [run_case(name, [fr[i] for i in idx], intr, [ref_pose]) for idx in sets[key]]
        ok = [r for r in recs if r["success"]]
        rows.append({"case": name, "runs": len(recs), "success": len(ok),
                     "wrong": sum(r["err_deg"] > 1.0 or r["err_m"] > 0.5 for r in ok),
                     "coverage_2sigma": (sum(r["covered_2sigma"] for r in ok) / len(ok)) if ok else None,
                     "err_deg_max": max((r["err_deg"] for r in ok), default=None),
                     "err_m_max": max((r["err_m"] for r in ok), default=None),
                     "refusals": sorted({r["refusal"] for r in recs if not r["success"]}),
                     "records": [{k: v for k, v in r.items() if k != "T"} for r in recs]})
        print(f"{name}: {len(ok)}/{len(recs)} accepted, wrong {rows[-1]['wrong']}, 2-sigma coverage "
              f"{rows[-1]['coverage_2sigma']}, max err {rows[-1]['err_deg_max']} deg / {rows[-1]['err_m_max']} m",
              flush=True)
    return rows


def pandaset_frames(root: Path):
    """PandaSet sequence ``root`` (no images) as ``(seq, truths, det, proj)``: the true poses, the
    frames with the shipped detector's 2D boxes (score >= 0.3) and with projected cuboids, both
    without extrinsics."""
    from xcalib.calib.pose import Pose
    from xcalib.data.boxes2d import synthetic_2d_boxes
    from xcalib.formats.pandaset import PandaSetFrames

    seq = PandaSetFrames(root, read_images=False)
    frames = [seq[i] for i in range(len(seq))]
    truths = [Pose.parse(np.asarray(f.extrinsics)) for f in frames]
    seen = [dataclasses.replace(f, extrinsics=None) for f in frames]
    det = [with_detections(f, DETS / "yolox_nano_1280" / "pandaset" / f"{f.frame_key[-2:]}.json", 0.3) for f in seen]
    proj = [dataclasses.replace(synthetic_2d_boxes(f, seed=i), extrinsics=None, match_matrix=None)
            for i, f in enumerate(frames)]
    return seq, truths, det, proj


def pandaset_cases(follow: bool = True) -> list[dict]:
    root = SHARED / "pandaset_002"
    if not root.exists() or not DETS.exists():
        return [{"case": "pandaset", "skipped": f"data not found: {root} / {DETS}"}]
    seq, truths, det, proj = pandaset_frames(root)
    out = []
    for name, fr in (("PandaSet detector 1280 score>=0.3", det), ("PandaSet projected cuboids", proj)):
        rec = run_case(name, fr, seq.intrinsics, truths)
        rec["advice_chain"] = follow_advice(fr, seq.intrinsics, truths, rec) if follow else []
        out.append(rec)
    return out


def _print(rows: list[dict]) -> None:
    print(f"\n{'case':38s} {'ok':>3s} {'refusal':24s} {'pairs':>5s} {'err deg':>8s} {'err m':>7s} "
          f"{'sig deg':>8s} {'sig m':>7s} {'in 2s':>5s} {'s':>6s}")
    for r in rows:
        if "skipped" in r:
            print(f"{r['case']:38s} skipped: {r['skipped']}")
            continue
        f = (lambda k, w, p: f"{r[k]:{w}.{p}f}" if r.get(k) is not None else " " * (w - 1) + "-")
        print(f"{r['case']:38s} {'yes' if r['success'] else 'no':>3s} {r['refusal'][:24]:24s} {r['n_pairs']:5d} "
              f"{f('err_deg', 8, 3)} {f('err_m', 7, 3)} {f('sigma_deg', 8, 3)} {f('sigma_m', 7, 3)} "
              f"{str(r.get('covered_2sigma', '-')):>5s} {r['time_s']:6.1f}")
        if r.get("box_fit"):
            print(f"{'':38s} box model: {r['box_fit']}")
        if not r["success"]:
            print(f"{'':38s} {r['message'][:150]}")
        for c in r.get("advice_chain", []):
            print(f"{'':38s} -> {c['case'].strip()}: {'success' if c['success'] else c['refusal']}"
                  f"{' (LOOP)' if c.get('loop') else ''} err {c.get('err_deg', float('nan')):.3f} deg / "
                  f"{c.get('err_m', float('nan')):.3f} m")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--only", choices=("a9", "pandaset"), default=None)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--subsets", type=int, default=0, help="also N random A9 subsets (labelled 8, detector 12 frames)")
    args = ap.parse_args(argv)
    rows: list[dict] = []
    if args.only in (None, "a9"):
        rows += a9_cases()
    if args.only in (None, "pandaset"):
        rows += pandaset_cases()
    _print(rows)
    subs = a9_subsets(args.subsets) if args.subsets else []
    if args.only is None or args.out != OUT:
        write_result(args.out, {"machine": machine_info(), "command": " ".join(sys.argv),
                                "rows": [{k: v for k, v in r.items() if k != "T"} for r in rows], "a9_subsets": subs})
    return 0


if __name__ == "__main__":
    sys.exit(main())
