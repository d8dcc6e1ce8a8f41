"""Few frames with 1-2 objects each: what the frame-halves guard (``few_matches_per_half``) refuses (issue 25).

Each case is calibrated as the package does, and again with the guard skipped where it fired (the
verdict judged as if the frame halves were available: the rest of the verdict and the misfit checks
then decide). Per case: the verdict, the matched pairs, the pose's error against the truth (the
refused pose for a refusal), whether the focal length was estimated, and the same with the guard
skipped. A pose is "right" within 0.3 deg / 0.2 m, "wrong" beyond 1 deg or 0.5 m (the benchmarks' line).

    python scripts/few_frames_audit.py real                    # KITTI labels / detector boxes (5 frames, leave-one-out)
    python scripts/few_frames_audit.py sparse [--seeds 12] [--frames 5,8] [--conditions exact,noisy,outline,noisy_outline]

``sparse``: synthetic roadside sites thinned to 1-2 objects per frame (``bench_calibration_sparse``:
1 px 2D noise, 10 % missed and 5 % false 2D boxes), exact or noisy (the generator's default) 3D boxes,
and with ``outline`` the 2D boxes as a detector's visible outline (``data.synth.detector``). Prints one
JSON line per case and a count per (condition, frames, verdict, verdict without the guard, pose class).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
RIGHT, LINE = (0.3, 0.2), (1.0, 0.5)


def pose_class(err) -> str:
    if err is None:
        return "no pose"
    if err[0] <= RIGHT[0] and err[1] <= RIGHT[1]:
        return "right"
    return "within line" if err[0] <= LINE[0] and err[1] <= LINE[1] else "WRONG"


def _calibrate(frames, intr, skip_guard: bool):
    import xcalib.calib.api as api
    from xcalib.calib import decision

    def verdict(ev, config):
        if skip_guard and ev.most_per_frame < 3 and not ev.halves_available:
            return decision.verdict(dataclasses.replace(ev, halves_available=True), config)
        return decision.verdict(ev, config)

    saved = api.verdict
    api.verdict = verdict
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return api.calibrate(frames, intr)
    finally:
        api.verdict = saved


def _error(res, T) -> list[float] | None:
    from xcalib.calib.pose import Pose

    d = res.diagnostics
    P = res.extrinsics if res.success else (np.asarray(d.refused_T) if d.refused_T is not None else None)
    if P is None:
        return None
    e = Pose.parse(np.asarray(P)).delta(Pose.parse(np.asarray(T)))
    return [round(float(np.linalg.norm(e[:3])), 4), round(float(np.linalg.norm(e[3:])), 4)]


def audit(name: str, frames, intr, T) -> dict:
    res = _calibrate(frames, intr, False)
    sc = res.diagnostics.selfcal
    rec = {"case": name, "verdict": res.diagnostics.refusal or "ok", "n_pairs": int(res.n_pairs),
           "error": _error(res, T), "focal_estimated": bool(sc.focal_estimated), "focal_scale": sc.focal_scale}
    if res.diagnostics.refusal == "few_matches_per_half":
        alt = _calibrate(frames, intr, True)
        rec.update(without_guard=alt.diagnostics.refusal or "ok", error_without_guard=_error(alt, T))
    print(json.dumps(rec), flush=True)
    return rec


def real() -> list[dict]:
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    import bench_coverage_real as B

    from xcalib.formats.kitti import kitti_frames

    root = B.SHARED / "kitti" / "openpcdet_pr653" / "training"
    seq = kitti_frames(root, ids=[1, 2, 3, 4, 5])
    frames = [seq[i] for i in range(len(seq))]
    T, K = np.asarray(frames[0].extrinsics), frames[0].intrinsics
    det = [B._det(f, B.DETS / "yolox_nano_1280" / "kitti" / f"{f.frame_key}.json") for f in frames]
    sets = [("frames 1-5", list(range(5)))] + B._leave_one_out(5)
    return [audit(f"KITTI {kind} {n}", [src[i] for i in idx], K, T)
            for kind, src in (("labels", frames), ("detector 1280", det)) for n, idx in sets]


def sparse_recording(seed: int, n_frames: int, noisy_3d: bool, outline: bool, stride: int = 10):
    """(frames without match matrix, site) as ``bench_calibration_sparse.sparse_recording``, optionally
    with the 2D boxes drawn as a detector's visible outline before thinning."""
    if str(BENCH) not in sys.path:
        sys.path.insert(0, str(BENCH))
    from bench_calibration import NOISE_3D_OFF
    from bench_calibration_sparse import thin_frame

    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.data.synth.detector import DetectorStyle, detector_frame

    site = sample_site(seed, preset="roadside")
    raw = generate_frames(site, n_frames * stride, seed=seed, render_images=False, lidar=False, miss_rate_2d=0.1,
                          false_positive_rate_2d=0.05, box_noise_px=1.0,
                          **({} if noisy_3d else NOISE_3D_OFF))[::stride]
    if outline:
        style = DetectorStyle(outline=True, merge_prob=0.0, class_misses=False, part_boxes=False, score_noise=False)
        raw = [detector_frame(f, style, (site.width, site.height), site.seed) for f in raw]
        raw = [dataclasses.replace(f, match_matrix=_same_ids(f.meta)) for f in raw]
    rng = np.random.default_rng([seed, 4242])
    thin = [thin_frame(f, rng, max_shared=2) for f in raw]
    return [dataclasses.replace(f, extrinsics=None, match_matrix=None) for f in thin], site


def _same_ids(meta) -> np.ndarray:
    i2, i3 = np.asarray(meta["ids_2d"]), np.asarray(meta["ids_3d"])
    return (i2[:, None] == i3[None, :]) & (i2[:, None] >= 0)


def sparse(seeds: int, n_frames: list[int], conditions: list[str]) -> list[dict]:
    out = []
    for cond in conditions:
        for nf in n_frames:
            for s in range(seeds):
                frames, site = sparse_recording(s, nf, "noisy" in cond, "outline" in cond)
                rec = audit(f"{cond} {nf} frames seed {s}", frames, site.intrinsics, site.T_cam_lidar)
                out.append({**rec, "condition": cond, "frames": nf})
    return out


def table(recs: list[dict]) -> None:
    c = Counter()
    for r in recs:
        err = r.get("error_without_guard", r["error"])
        c[(r.get("condition", "real"), r.get("frames", 0), r["verdict"], r.get("without_guard", "-"), pose_class(err))] += 1
    print("| condition | frames | verdict | without the guard | pose | n |\n|---|---|---|---|---|---|")
    for k in sorted(c):
        print("| " + " | ".join(str(v) for v in k) + f" | {c[k]} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["real", "sparse"])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--frames", default="5,8")
    ap.add_argument("--conditions", default="exact,noisy,outline,noisy_outline")
    a = ap.parse_args(argv)
    recs = real() if a.what == "real" else sparse(a.seeds, [int(x) for x in a.frames.split(",")],
                                                  a.conditions.split(","))
    table(recs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
