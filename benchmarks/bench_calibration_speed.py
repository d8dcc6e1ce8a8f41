"""Calibration speed against 0.5.0, as ratios measured in one run (issue 29).

The current tree (``src/``) and 0.5.0 as released (tag ``v0.5.0`` = commit ``4d6cc5d``, exported with ``git archive``
into a temporary folder -- nothing in the repository changes) each calibrate the same cases, one
fresh child process per (case, version) with ``PYTHONPATH`` pointing at that version's ``src``
and ``OMP_NUM_THREADS=1``; the two versions of a case run back to back, so both see the same
machine load. Both run one process (``workers=1``). Reported per case: CPU time (``time.process_time`` of the call, the figure to
read on a shared machine) and wall time of each version, the CPU ratio old / new, whether the
verdicts are the same and how far apart the poses are (deg / m), peak RSS.

Cases:

* ``a9``: the 16 real A9 frames (``../shared/data/a9_sample``; skipped when absent);
* ``synth20``: a 20-frame synthetic roadside site (realism ``clean`` condition, first
  identifiable seed);
* ``synth1000``: a 1,000-frame synthetic recording of one site (1 px 2D noise, exact 3D boxes);
* ``dense``: 10 frames with 100 2D and 100 3D boxes each (``bench_calibration_memory``'s
  ``100x100``: a 360-degree LiDAR at a busy junction);
* ``dense20`` / ``dense80`` / ``dense200``: 20 frames of a busy junction with about 20 / 80 / 200
  2D boxes per frame and more 3D boxes (``bench_calibration_memory.junction_frames``: a wide 4K
  camera, a 360-degree LiDAR; issue 29 asks 80 and 200 to succeed within 2x and 5x the CPU time of
  20 and under 1 GB: run the three in one command, e.g. ``--cases dense20 dense80 dense200``);
* ``consensus_a9``: ``consensus_matches`` on each A9 frame (no site weights): CPU ms per frame
  and whether the matches are the same;
* ``realism:CONDITION:SEED``: one realism-suite site (``xcalib.data.synth.realism``), for the
  same-verdict check across conditions.

With ``--profile`` the current code's calibration of ``a9`` and ``synth20`` is also split by
stage (CPU seconds and share: search, refinement, misfit checks, uncertainty, ...). With
``--parallel a9 synth1000`` those cases also run with ``workers=2``: the wall-clock speed-up over
``workers=1`` (meaningful only on an otherwise idle machine with 2+ cores) and the same result.
Prints a table and writes ``benchmarks/results/calibration_speed.json``.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibration_speed.py \
        [--cases a9 synth20 synth1000 dense dense20 dense80 dense200 consensus_a9] [--base v0.5.0] [--profile] [--frames-long 1000] [--merge]

``--merge`` re-runs only the cases named and replaces their rows in the existing JSON (e.g. the
``synth1000`` row after frame selection: ``--cases synth1000 --parallel synth1000 --merge``);
every row records the command that produced it (``rerun``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _provenance import base_050  # noqa: E402
from bench_calibration import machine_info, write_result  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("XCALIB_SHARED_DATA", REPO.parent / "shared" / "data"))
OUT = REPO / "benchmarks" / "results" / "calibration_speed.json"
BASE_COMMIT = base_050()  # 0.5.0 as released: the v0.5.0 tag (= 4d6cc5d)
CASES = ("a9", "synth20", "synth1000", "dense", "dense20", "dense80", "dense200", "consensus_a9")
STAGES = ("prepare_frames", "_search", "_refine_candidates", "_choose_box_model", "decide_selfcal",
          "estimate_uncertainty", "_misfit", "_mirror_score", "_second_pose", "_lens_check", "focal_fit",
          "principal_point_check", "time_offset_check")


# --------------------------------------------------------------------------- child side

def _case_frames(case: str, frames_long: int):
    """(frames, intrinsics, truth [4,4] or None) of a case."""
    if case in ("a9", "consensus_a9"):
        from xcalib.io.frames import read_frames

        seq = read_frames(SHARED / "a9_sample")
        return [seq[i] for i in range(len(seq))], seq.intrinsics, None
    if case == "synth20":
        from xcalib.data.synth.realism import identifiable_site_seeds, make_realism_case

        c = make_realism_case("clean", identifiable_site_seeds(1, 20)[0], 20)
        return list(c.frames), c.intrinsics_given, c.T_cam_lidar
    if case == "synth1000":
        from bench_calibration import NOISE_3D_OFF
        from xcalib.data.synth import generate_frames, sample_site

        site = sample_site(0, preset="roadside")
        frames = generate_frames(site, frames_long, seed=0, render_images=False, lidar=False, miss_rate_2d=0.1,
                                 false_positive_rate_2d=0.05, box_noise_px=1.0, **NOISE_3D_OFF)
        return frames, site.intrinsics, site.T_cam_lidar
    if case.startswith("realism:"):  # realism:CONDITION:SEED, e.g. realism:mirrored:2
        from xcalib.data.synth.realism import make_realism_case

        _, cond, seed = case.split(":")
        c = make_realism_case(cond, int(seed), 20)
        return list(c.frames), c.intrinsics_given, c.T_cam_lidar
    if case == "dense":
        from bench_calibration_memory import crowded_frames

        frames, T = crowded_frames(0, 10, 100, 100)
        return frames, frames[0].intrinsics, T
    if case in ("dense20", "dense80", "dense200"):  # a busy junction, about N 2D boxes per frame
        from bench_calibration_memory import junction_frames

        frames, T = junction_frames(0, 20, int(case[5:]))
        return frames, frames[0].intrinsics, T
    raise ValueError(f"unknown case {case!r}")


def _stage_timers():
    """Wrap the calibration's stages (module attributes of ``xcalib.calib.api``) with CPU timers."""
    import xcalib.calib.api as api

    acc: dict[str, float] = {}
    for name in STAGES:
        f = getattr(api, name, None)
        if f is None:
            continue

        def wrapped(*a, _f=f, _n=name, **k):
            c0 = time.process_time()
            try:
                return _f(*a, **k)
            finally:
                acc[_n] = acc.get(_n, 0.0) + time.process_time() - c0

        setattr(api, name, wrapped)
    return acc


def _config(workers: int | None):
    """CalibConfig with ``workers`` where this version has the field (0.5.0 has not: one process)."""
    from dataclasses import fields

    from xcalib.calib.config import CalibConfig

    names = {f.name for f in fields(CalibConfig)}
    return CalibConfig(workers=workers) if workers is not None and "workers" in names else CalibConfig()


def child(case: str, frames_long: int, profile: bool, workers: int | None = 1) -> dict:
    import resource
    import warnings

    warnings.simplefilter("ignore")
    frames, intr, T = _case_frames(case, frames_long)
    rec: dict = {"case": case, "frames": len(frames),
                 "n_2d": int(sum(len(np.asarray(f.bboxes_2d).reshape(-1, 4)) for f in frames)),
                 "n_3d": int(sum(len(np.asarray(f.bboxes_3d)) for f in frames))}
    if case == "consensus_a9":
        from xcalib.calib.consensus import consensus_matches

        consensus_matches(frames[0], intr)  # imports and first-call set-up are not matching time
        cpu, matches = [], []
        for f in frames:
            c0 = time.process_time()
            m = consensus_matches(f, intr)
            cpu.append(time.process_time() - c0)
            matches.append(m.pairs.tolist())
        rec.update(cpu_s=float(np.sum(cpu)), cpu_ms_per_frame=1e3 * float(np.mean(cpu)), matches=matches)
        return rec
    from xcalib.calib.api import calibrate

    acc = _stage_timers() if profile else None
    config = _config(workers)
    ch0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0, c0 = time.perf_counter(), time.process_time()
    res = calibrate(frames, intr, config)
    rec["cpu_s"], rec["wall_s"] = time.process_time() - c0, time.perf_counter() - t0
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    rec["workers"] = getattr(config, "workers", 1)
    rec["children_cpu_s"] = ch.ru_utime + ch.ru_stime - ch0.ru_utime - ch0.ru_stime
    rec["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 10
    d = res.diagnostics
    Tr = res.extrinsics if res.rotation is not None else getattr(d, "refused_T", None)
    rec.update(success=bool(res.success), refusal=d.refusal, message=res.message, n_pairs=res.n_pairs,
               T=None if Tr is None else np.asarray(Tr, dtype=float).tolist())
    if res.success and T is not None:
        rec["rot_deg"], rec["trans_m"] = (float(v) for v in res.pose_error(T))
    if acc is not None:
        rec["stages_cpu_s"] = {k: round(v, 3) for k, v in sorted(acc.items(), key=lambda x: -x[1])}
    return rec


# --------------------------------------------------------------------------- parent side

def export_base(commit: str, dest: Path) -> Path:
    """``src/`` of ``commit`` (git archive; the repository is not changed) under ``dest``."""
    tar = subprocess.run(["git", "-C", str(REPO), "archive", commit, "src"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=tar, check=True)
    return dest / "src"


def run_child(src: Path, case: str, frames_long: int, profile: bool, timeout: float, workers: int = 1) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", case, "--frames-long", str(frames_long),
           "--workers", str(workers)]
    if profile:
        cmd.append("--profile")
    try:
        p = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"case": case, "error": f"timed out after {timeout:.0f} s"}
    line = next((ln for ln in reversed(p.stdout.splitlines()) if ln.startswith("{")), None)
    if p.returncode != 0 or line is None:
        return {"case": case, "error": f"exit {p.returncode}: {p.stderr.strip()[-400:]}"}
    return json.loads(line)


def _pose_gap(a: dict, b: dict) -> tuple[float, float] | None:
    if not a.get("T") or not b.get("T"):
        return None
    from scipy.spatial.transform import Rotation

    Ta, Tb = np.asarray(a["T"]), np.asarray(b["T"])
    rot = float(np.degrees(np.linalg.norm(Rotation.from_matrix(Ta[:3, :3] @ Tb[:3, :3].T).as_rotvec())))
    return rot, float(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]))


def compare(case: str, old: dict, new: dict) -> dict:
    row = {"case": case, "base": old, "current": new}
    if "error" in old or "error" in new:
        return row
    row["cpu_ratio"] = old["cpu_s"] / max(new["cpu_s"], 1e-9)
    if case == "consensus_a9":
        row["same_matches"] = old["matches"] == new["matches"]
        return row
    row["same_verdict"] = old["success"] == new["success"] and old["refusal"] == new["refusal"]
    gap = _pose_gap(old, new)
    if gap is not None:
        row["pose_gap_deg"], row["pose_gap_m"] = gap
    return row


def print_table(rows: list[dict]) -> None:
    print(f"\n{'case':14s} {'frames':>6s} {'boxes 2D/3D':>12s} {'0.5.0 cpu':>10s} {'now cpu':>9s} {'ratio':>6s} "
          f"{'verdict':>18s} {'pose gap':>18s} {'rss MB':>7s}")
    for r in rows:
        o, n = r["base"], r["current"]
        if "error" in n or ("error" in o and not r["case"].startswith("dense")):
            print(f"{r['case']:14s} error: {n.get('error') or o.get('error')}")
            continue
        if "error" in o:  # the dense junction's generator settings are newer than 0.5.0: the current code alone
            verdict = n["refusal"] or "success"
            gap = f"{n['rot_deg']:.4f} deg {n['trans_m']:.4f} m to truth" if "rot_deg" in n else "-"
            print(f"{r['case']:14s} {n['frames']:6d} {n['n_2d']}/{n['n_3d']:>6} {'n/a':>10s} {n['cpu_s']:8.2f}s {'':6s} "
                  f"{verdict:>18s} {gap:>18s} {n.get('peak_rss_mb', 0):7.0f}")
            continue
        boxes = f"{n['n_2d']}/{n['n_3d']}"
        if r["case"] == "consensus_a9":
            print(f"{r['case']:14s} {n['frames']:6d} {boxes:>12s} {o['cpu_ms_per_frame']:8.0f}ms {n['cpu_ms_per_frame']:7.0f}ms "
                  f"{r['cpu_ratio']:6.2f} {'same matches' if r['same_matches'] else 'MATCHES DIFFER':>18s}")
            continue
        verdict = (n["refusal"] or "success") + ("" if r["same_verdict"] else f" (was {o['refusal'] or 'success'})")
        gap = f"{r['pose_gap_deg']:.4f} deg {r['pose_gap_m']:.4f} m" if "pose_gap_deg" in r else "-"
        print(f"{r['case']:14s} {n['frames']:6d} {boxes:>12s} {o['cpu_s']:9.2f}s {n['cpu_s']:8.2f}s {r['cpu_ratio']:6.2f} "
              f"{verdict:>18s} {gap:>18s} {n.get('peak_rss_mb', 0):7.0f}")
    sc = dense_scaling(rows)
    if sc:
        print("\ndense scaling (current code, CPU vs dense20; issue 29: 80 within 2x, 200 within 5x, 0 wrong, < 1 GB): "
              + "; ".join(f"{c} x{v['cpu_vs_dense20']:.2f} ({v['verdict']}, {v['error']}, {v['peak_rss_mb']:.0f} MB)"
                          for c, v in sc.items()))
    for r in rows:
        st = r["current"].get("stages_cpu_s")
        if st:
            tot = r["current"]["cpu_s"]
            print(f"\nprofile split, {r['case']} (current code, CPU s of {tot:.2f}; nested stages overlap): "
                  + ", ".join(f"{k} {v:.2f} ({100 * v / tot:.0f} %)" for k, v in st.items()))


def dense_scaling(rows: list[dict]) -> dict:
    """Per dense case run with ``dense20`` in the same run: the current code's CPU time over
    dense20's, the verdict, the pose error to the truth and the peak RSS."""
    cur = {r["case"]: r["current"] for r in rows if isinstance(r.get("current"), dict) and "error" not in r["current"]}
    if "dense20" not in cur:
        return {}
    out = {}
    for c in ("dense20", "dense80", "dense200"):
        n = cur.get(c)
        if n is None:
            continue
        err = (f"{n['rot_deg']:.3f} deg / {n['trans_m']:.3f} m" if "rot_deg" in n else "-")
        out[c] = {"cpu_vs_dense20": n["cpu_s"] / max(cur["dense20"]["cpu_s"], 1e-9),
                  "verdict": n["refusal"] or "success", "error": err, "peak_rss_mb": n.get("peak_rss_mb", 0.0),
                  "n_2d_per_frame": n["n_2d"] / n["frames"], "n_3d_per_frame": n["n_3d"] / n["frames"]}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES),
                    help=f"{', '.join(CASES)} or realism:CONDITION:SEED (same verdict and pose on a realism site)")
    ap.add_argument("--base", default=BASE_COMMIT, help="commit to compare with (default: 0.5.0 as landed)")
    ap.add_argument("--frames-long", type=int, default=1000, help="frames of the synth1000 case")
    ap.add_argument("--profile", action="store_true", help="split the current code's a9 / synth20 time by stage")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per child")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--parallel", nargs="*", default=[], choices=CASES,
                    help="cases also run by the current code with workers=2: wall-clock speed-up over workers=1")
    ap.add_argument("--merge", action="store_true",
                    help="re-run only --cases (and --parallel) and replace their rows in the existing --out file; the "
                         "other rows are kept as they are (each row keeps its own command in 'rerun')")
    ap.add_argument("--workers", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    bad = [c for c in args.cases if c not in CASES and not (c.startswith("realism:") and c.count(":") == 2)]
    if bad:
        ap.error(f"unknown case(s) {bad}")
    if args.child:
        print(json.dumps(child(args.child, args.frames_long, args.profile, args.workers), default=float))
        return 0
    cases = [c for c in args.cases if not (c in ("a9", "consensus_a9") and not (SHARED / "a9_sample").is_dir())]
    rows = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="xcalib-base-") as tmp:
        base_src = export_base(args.base, Path(tmp))
        for case in cases:
            prof = args.profile and case in ("a9", "synth20")
            old = run_child(base_src, case, args.frames_long, False, args.timeout)
            new = run_child(REPO / "src", case, args.frames_long, prof, args.timeout)
            rows.append(compare(case, old, new))
            print(f"{case}: 0.5.0 {old.get('cpu_s', float('nan')):.2f} s CPU, now {new.get('cpu_s', float('nan')):.2f} s",
                  flush=True)
            _write(args, argv, rows, [], t0, partial=True)  # what is done so far survives an interrupted run
    par = []
    for case in [c for c in args.parallel if c in cases and c != "consensus_a9"]:
        one = run_child(REPO / "src", case, args.frames_long, False, args.timeout, workers=1)
        two = run_child(REPO / "src", case, args.frames_long, False, args.timeout, workers=2)
        row = {"case": case, "workers1": one, "workers2": two}
        if "error" not in one and "error" not in two:
            row["wall_speedup"] = one["wall_s"] / max(two["wall_s"], 1e-9)
            row["same_pose"] = one["T"] == two["T"] and one["refusal"] == two["refusal"]
        par.append(row)
    print_table(rows)
    for r in par:
        if "wall_speedup" in r:
            o, t = r["workers1"], r["workers2"]
            print(f"\nworkers=2 vs 1, {r['case']}: wall {o['wall_s']:.2f} -> {t['wall_s']:.2f} s (x{r['wall_speedup']:.2f}); "
                  f"CPU parent {t['cpu_s']:.2f} + children {t['children_cpu_s']:.2f} s vs {o['cpu_s']:.2f} s; "
                  f"{'same result' if r['same_pose'] else 'RESULT DIFFERS'}")
    _write(args, argv, rows, par, t0)
    return 0


def merged_rows(old: list[dict], new: list[dict]) -> list[dict]:
    """``old`` rows with those of the cases in ``new`` replaced (in place of the old row; new cases appended)."""
    fresh = {r["case"]: r for r in new}
    out = [fresh.pop(r["case"], r) for r in old]
    return out + [r for r in new if r["case"] in fresh]


def _write(args, argv, rows: list, par: list, t0: float, partial: bool = False) -> None:
    command = "benchmarks/bench_calibration_speed.py " + " ".join(argv if argv is not None else sys.argv[1:])
    for r in rows + par:
        r.setdefault("rerun", command)
    result = {"benchmark": "calibration_speed", "base_commit": args.base, "machine": machine_info(),
              "command": command, "wall_s": time.perf_counter() - t0, "cases": rows, "parallel": par,
              "dense_scaling": dense_scaling(rows)}
    if args.merge and args.out.exists():
        # only the cases run now are replaced; the file's command stays the full run's (the freshness test re-runs it)
        prev = json.loads(args.out.read_text())
        result.update(command=prev.get("command", command), cases=merged_rows(prev.get("cases", []), rows),
                      parallel=merged_rows(prev.get("parallel", []), par),
                      merged=prev.get("merged", []) + [{"command": command, "cases": [r["case"] for r in rows + par]}])
        result["dense_scaling"] = dense_scaling(result["cases"])
        if partial:  # the file is replaced only once the merge is complete (it keeps the other rows)
            return
    if partial:
        result["partial"] = True
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2, default=float))
    else:
        write_result(args.out, result)


if __name__ == "__main__":
    sys.exit(main())
