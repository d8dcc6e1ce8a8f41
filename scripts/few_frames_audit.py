"""Few frames with 1-2 objects each: what the frame-halves guard (``few_matches_per_half``) refuses (issue 25).

Each case is calibrated as the package does, and again with the guard skipped where it fired (the
verdict judged as if the frame halves were available: the rest of the verdict and the misfit checks
then decide). Per case: the verdict, the matched pairs, the pose's error against the truth (the
refused pose for a refusal), whether the focal length was estimated, and the same with the guard
skipped. A pose is "right" within 0.3 deg / 0.2 m, "wrong" beyond 1 deg or 0.5 m (the benchmarks' line).

    python scripts/few_frames_audit.py real                    # KITTI labels / detector boxes (5 frames, leave-one-out)
    python scripts/few_frames_audit.py sparse [--seeds 12] [--frames 5,8] [--conditions exact,noisy,outline,noisy_outline]
    python scripts/few_frames_audit.py coverage [--seeds 40] [--frames 5,8] [--conditions exact,noisy] [--first-seed 0] [--out recs.jsonl]
    python scripts/few_frames_audit.py summary --jsonl recs.jsonl [more.jsonl ...]

``sparse``: synthetic roadside sites thinned to 1-2 objects per frame (``bench_calibration_sparse``:
1 px 2D noise, 10 % missed and 5 % false 2D boxes), exact or noisy (the generator's default) 3D boxes,
and with ``outline`` the 2D boxes as a detector's visible outline (``data.synth.detector``). Prints one
JSON line per case and a count per (condition, frames, verdict, verdict without the guard, pose class).

``coverage`` (session 11, K2): the same sparse recordings calibrated once with the guard skipped; per case
the signed 6-vector error (deg, m; ``Pose.delta`` against the truth), the reported per-axis sigma and its
parts (``diagnostics.uncertainty``), for every pose (successes and refused poses alike). The summary per
(condition, frames): the per-axis 2-sigma coverage with its 95 % Clopper-Pearson interval, the rms of
z = error / sigma per axis, the empirical spread of the error over seeds (rms) against the rms of the
reported sigma and of each of its parts.
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
    """The calibration's result, with the frame-halves guard skipped if ``skip_guard``."""
    if skip_guard:
        return _calibrate_flagged(frames, intr)[0]
    import xcalib.calib.api as api

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return api.calibrate(frames, intr)


def _calibrate_flagged(frames, intr):
    """(result with the frame-halves guard skipped, whether the guard would have fired)."""
    import xcalib.calib.api as api
    from xcalib.calib import decision

    fired = []

    def verdict(ev, config):
        if ev.most_per_frame < 3 and not ev.halves_available:
            fired.append(True)
            return decision.verdict(dataclasses.replace(ev, halves_available=True), config)
        return decision.verdict(ev, config)

    saved = api.verdict
    api.verdict = verdict
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return api.calibrate(frames, intr), bool(fired)
    finally:
        api.verdict = saved


def coverage_case(name: str, frames, intr, T) -> dict:
    """One recording with the guard skipped: verdict, signed error, reported sigma and its parts."""
    from xcalib.calib.pose import Pose

    res, fired = _calibrate_flagged(frames, intr)
    d = res.diagnostics
    P = res.extrinsics if res.success else (np.asarray(d.refused_T) if d.refused_T is not None else None)
    rec = {"case": name, "verdict": d.refusal or "ok", "guard_fired": fired, "n_pairs": int(res.n_pairs),
           "n_objects": int(d.uncertainty.n_objects), "focal_estimated": bool(d.selfcal.focal_estimated)}
    if P is not None:
        delta = Pose.parse(np.asarray(P)).delta(Pose.parse(np.asarray(T)))
        sd = np.concatenate([np.asarray(res.rotation_std_deg, float), np.asarray(res.translation_std_m, float)])
        rec.update(delta=[float(v) for v in delta], sigma=[float(v) for v in sd],
                   parts={k: v for k, v in d.uncertainty.__dict__.items() if k != "box_model"})
    print(json.dumps(rec), flush=True)
    return rec


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    from scipy.stats import beta

    a = (1 - level) / 2
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a, k + 1, n - k))
    return lo, hi


PART_NAMES = ("jacobian", "clusters", "jackknife", "frames", "objects", "occlusion", "floor", "outline", "object_outline",
              "centre_model")


def coverage_summary(recs: list[dict], only_ok: bool = False) -> None:
    """Per (condition, frames): per-axis 2-sigma coverage (pooled over axes, with its Clopper-Pearson
    interval; per axis), rms z per axis, and the error's rms over seeds against the rms of the sigma and
    of each part (6 axes: rx ry rz deg, tx ty tz m)."""
    groups: dict = {}
    for r in recs:
        if "delta" in r and (not only_ok or r["verdict"] == "ok"):
            groups.setdefault((r["condition"], r["frames"]), []).append(r)
    for key in sorted(groups):
        g = groups[key]
        e, sd = np.array([r["delta"] for r in g]), np.array([r["sigma"] for r in g])
        ok = np.abs(e) <= 2 * sd
        k, n = int(ok.sum()), ok.size
        lo, hi = clopper_pearson(k, n)
        wrong = sum(pose_class([float(np.linalg.norm(x[:3])), float(np.linalg.norm(x[3:]))]) == "WRONG" and r["verdict"] == "ok"
                    for x, r in zip(e, g))
        from xcalib.calib.diagnostics import bound95

        b = np.array([[bound95(x[:3]), bound95(x[3:])] for x in sd])
        en = np.stack([np.linalg.norm(e[:, :3], axis=1), np.linalg.norm(e[:, 3:], axis=1)], axis=1)
        inb = int(np.all(en <= b, axis=1).sum())
        blo, bhi = clopper_pearson(inb, len(g))
        print(f"\n{key[0]} {key[1]} frames: {len(g)} poses ({sum(r['verdict'] == 'ok' for r in g)} successes, "
              f"{wrong} wrong successes); 2-sigma per-axis coverage {k}/{n} = {k / n:.3f} [CP95 {lo:.3f}, {hi:.3f}]; "
              f"poses with all 6 axes covered {int(ok.all(axis=1).sum())}/{len(g)}; within the result's 95 % bound "
              f"(rotation and translation) {inb}/{len(g)} [CP95 {blo:.3f}, {bhi:.3f}]")
        rows = {"cover 2sd": ok.mean(axis=0), "rms z": np.sqrt(np.mean((e / sd) ** 2, axis=0)),
                "rms error": np.sqrt(np.mean(e ** 2, axis=0)), "rms sigma": np.sqrt(np.mean(sd ** 2, axis=0))}
        for p in PART_NAMES:
            vals = [r["parts"].get(p) for r in g]
            if any(v is not None for v in vals):
                arr = np.array([np.abs(v) if v is not None else np.zeros(6) for v in vals], dtype=float)
                rows[f"rms {p} ({sum(v is not None for v in vals)})"] = np.sqrt(np.mean(arr ** 2, axis=0))
        cm = [r["parts"].get("centre_model") for r in g]
        if all(v is not None for v in cm):  # branch s11-D's part: the sigma if it were a floor of it
            sd2 = np.fmax(sd, np.array(cm, dtype=float))
            ok2 = np.abs(e) <= 2 * sd2
            b2 = np.array([[bound95(x[:3]), bound95(x[3:])] for x in sd2])
            lo2, hi2 = clopper_pearson(int(ok2.sum()), ok2.size)
            print(f"  with sigma = max(sigma, centre_model): 2-sigma per-axis {int(ok2.sum())}/{ok2.size} = {ok2.mean():.3f} "
                  f"[CP95 {lo2:.3f}, {hi2:.3f}]; within the 95 % bound {int(np.all(en <= b2, axis=1).sum())}/{len(g)}")
            rows["cover 2sd, max(sigma, centre_model)"] = ok2.mean(axis=0)
            rows["rms z, max(sigma, centre_model)"] = np.sqrt(np.mean((e / sd2) ** 2, axis=0))
        print("| | rx | ry | rz | tx | ty | tz |\n|---|---|---|---|---|---|---|")
        for name, v in rows.items():
            print(f"| {name} | " + " | ".join(f"{x:.3f}" for x in v) + " |")


def _dedupe(recs: list[dict]) -> list[dict]:
    """One record per (condition, frames, seed): the last one that keeps ``parts.centre_model``, else the last."""
    by: dict = {}
    for r in recs:
        k = (r["condition"], r["frames"], r["seed"])
        if k not in by or (r.get("parts") or {}).get("centre_model") is not None \
                or (by[k].get("parts") or {}).get("centre_model") is None:
            by[k] = r
    return list(by.values())


def coverage(seeds: int, n_frames: list[int], conditions: list[str], out: str | None, first: int = 0) -> list[dict]:
    recs = []
    fh = open(out, "a") if out else None
    try:
        for cond in conditions:
            for nf in n_frames:
                for s in range(first, first + seeds):
                    frames, site = sparse_recording(s, nf, "noisy" in cond, "outline" in cond)
                    rec = {**coverage_case(f"{cond} {nf} frames seed {s}", frames, site.intrinsics, site.T_cam_lidar),
                           "condition": cond, "frames": nf, "seed": s}
                    recs.append(rec)
                    if fh:
                        fh.write(json.dumps(rec) + "\n")
                        fh.flush()
    finally:
        if fh:
            fh.close()
    return recs


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
    from bench_calibration_detections import with_detections

    from xcalib.formats.kitti import kitti_frames

    root = B.SHARED / "kitti" / "openpcdet_pr653" / "training"
    seq = kitti_frames(root, ids=[1, 2, 3, 4, 5])
    frames = [seq[i] for i in range(len(seq))]
    T, K = np.asarray(frames[0].extrinsics), frames[0].intrinsics
    det = [with_detections(f, B.DETS / "yolox_nano_1280" / "kitti" / f"{f.frame_key}.json", B.SCORE_MIN)
           for f in frames]
    sets = [("frames 1-5", list(range(5)))] + B.leave_one_out(5)
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
    ap.add_argument("what", choices=["real", "sparse", "coverage", "summary"])
    ap.add_argument("--seeds", type=int, default=12)
    ap.add_argument("--frames", default="5,8")
    ap.add_argument("--conditions", default="exact,noisy,outline,noisy_outline")
    ap.add_argument("--first-seed", type=int, default=0, help="coverage: the first seed")
    ap.add_argument("--out", default=None, help="coverage: append each record to this .jsonl")
    ap.add_argument("--jsonl", nargs="*", default=[], help="summary: the .jsonl files written by coverage --out")
    a = ap.parse_args(argv)
    if a.what in ("coverage", "summary"):
        recs = (coverage(a.seeds, [int(x) for x in a.frames.split(",")], a.conditions.split(","), a.out, a.first_seed)
                if a.what == "coverage" else
                _dedupe([json.loads(line) for f in a.jsonl for line in Path(f).read_text().splitlines() if line.strip()]))
        print("\n## all poses (successes and refused poses, the guard skipped)")
        coverage_summary(recs)
        print("\n## successes only (the guard skipped)")
        coverage_summary(recs, only_ok=True)
        return 0
    recs = real() if a.what == "real" else sparse(a.seeds, [int(x) for x in a.frames.split(",")],
                                                  a.conditions.split(","))
    table(recs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
