"""Realism benchmark (issue 12 item 2, issue 13 item 4): the calibrator on synthetic sites bent the
way real sites are (``xcalib.data.synth.realism``; every condition's exact meaning is its
``description`` and the module docstring).

For each condition, the same ``--sites`` identifiable roadside sites (the first site seeds whose
*clean* 20 frames show >= 3 objects to both sensors and >= 20 true 2D-3D detections) are
calibrated with the public call ``xcalib.calibrate(case.frames, case.intrinsics_given)`` (no
initial guess, default options) and compared with the truth.

Columns: n (sites), success (share with ``success=True``), 4+ obj (successes / sites among those
whose frames show 4+ distinct objects to both sensors: a pose resting on fewer is refused
as not verifiable, ``decision``), wrong (successes with a rotation error
> 1 deg or a translation error > 0.5 m against the true ``T_cam_lidar``), median rotation /
translation error of the successes, 2-sigma coverage (share of the successes whose rotation error
<= 2 * norm(rotation_std_deg) AND translation error <= 2 * norm(translation_std_m), the norms of the
reported per-axis 1-sigma; rotation and translation coverage separately in the JSON), 95 % cov
(share of the successes whose rotation and translation errors lie within the 95 % radius of the
per-axis sigma, ``xcalib.calib.uncertainty.bound95``: what a success promises since 0.6), axis cov
(share of the success's 6 per-axis errors within 2x that axis's 1-sigma: ~95 % for a right sigma;
the norm form above reads 96-99 % for a right sigma), median
wall time of ``calibrate``. When the result carries estimated intrinsics / a time offset (issue
13), the JSON also records the focal ratio to the truth and the offset error per site.

With ``--selfcal`` every condition gains a row "<condition> +selfcal" calibrated with
``CalibConfig(refine_intrinsics=--refine-intrinsics, time_offset=--time-offset)`` (default "auto" /
"auto": the focal length and the time offset estimated where the data constrain them).

``--box-noise-px 4`` runs every condition with that 2D box noise instead of its own (1 px in the
base): the misfit checks lose power as the boxes get noisier, as a real detector's are.

Each run is stored under ``--label`` in ``benchmarks/results/calibration_realism.json`` (other
labels in the file are kept, so a BEFORE and an AFTER table live side by side). Each per-site
record's ``sigma_parts`` (the pieces of its sigma, 60 % of the records' bytes, read only by
``scripts/sigma_parts.py``) are kept beside it in ``calibration_realism_detail.json.gz`` (run label
-> condition -> seed; :func:`write_runs`, both files written atomically); :func:`load_runs` joins
them back.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_calibration_realism.py \
        [--sites 20] [--conditions clean,mirrored] [--jobs 1] [--label before] [--selfcal] [--box-noise-px 4]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "benchmarks" / "results" / "calibration_realism.json"
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibration import machine_info  # noqa: E402

WRONG_ROT_DEG, WRONG_TRANS_M = 1.0, 0.5
#: per-site fields stored in the compressed side file, not in the main JSON (no table or freshness test reads them)
DETAIL_FIELDS = ("sigma_parts",)


def detail_path(out: Path) -> Path:
    """The side file of ``out``: ``<stem>_detail.json.gz`` beside it."""
    return out.with_name(f"{out.stem}_detail.json.gz")


def load_runs(out: Path = OUT, detail: bool = True) -> dict:
    """The runs of ``out`` (label -> run), each per-site record with its ``DETAIL_FIELDS`` joined back
    from the side file (``detail``; a record whose detail is not there is left without them)."""
    import gzip

    runs = json.loads(out.read_text())["runs"] if out.exists() else {}
    side = detail_path(out)
    if not (detail and side.exists()):
        return runs
    extra = json.loads(gzip.decompress(side.read_bytes()))["runs"]
    for label, run in runs.items():
        for cond in run.get("conditions", []):
            per = extra.get(label, {}).get(cond.get("condition"), {})
            for rec in cond.get("per_site") or []:
                rec.update(per.get(str(rec.get("seed")), {}))
    return runs


def write_runs(out: Path, runs: dict) -> None:
    """``runs`` written to ``out`` with the per-site ``DETAIL_FIELDS`` moved to the gzip side file
    (:func:`detail_path`, deterministic bytes); each file written to a temporary file and renamed, the
    side file first (a reader of the main file alone never misses a field it reads)."""
    import gzip

    main_runs, extra = {}, {}
    for label, run in runs.items():
        conds = []
        for cond in run.get("conditions", []):
            if cond.get("per_site"):
                per = extra.setdefault(label, {}).setdefault(cond["condition"], {})
                slim = []
                for rec in cond["per_site"]:
                    moved = {k: rec[k] for k in DETAIL_FIELDS if k in rec}
                    if moved:
                        per[str(rec.get("seed"))] = moved
                    slim.append({k: v for k, v in rec.items() if k not in DETAIL_FIELDS})
                cond = {**cond, "per_site": slim}
            conds.append(cond)
        main_runs[label] = {**run, "conditions": conds}
    out.parent.mkdir(parents=True, exist_ok=True)
    side = detail_path(out)
    for path, data in ((side, gzip.compress(json.dumps({"runs": extra}, default=float).encode(), 9, mtime=0)),
                       (out, json.dumps({"runs": main_runs}, indent=1, default=float).encode())):
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(data)
        os.replace(tmp, path)


SELFCAL_SUFFIX = " +selfcal"


def run_case(task: tuple) -> dict:
    """Calibrate one (condition, site seed, frames[, selfcal options]) case; a JSON-ready record.
    With options (refine_intrinsics, time_offset) the row is "<condition> +selfcal"."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import warnings

    import xcalib
    from xcalib.calib.config import CalibConfig
    from xcalib.data.synth.realism import REALISM_CONDITIONS, make_realism_case

    name, seed, n_frames = task[:3]
    opts = task[3] if len(task) > 3 else None
    box_noise_px = task[4] if len(task) > 4 else None
    cond = REALISM_CONDITIONS[name]
    if box_noise_px is not None:  # every condition with noisier 2D boxes (--box-noise-px)
        cond = dataclasses.replace(cond, box_noise_px=box_noise_px)
    case = make_realism_case(cond, seed, n_frames)
    config = None if opts is None else CalibConfig(refine_intrinsics=opts[0], time_offset=opts[1])
    if opts is not None:
        name = name + SELFCAL_SUFFIX
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # fallbacks are recorded in the result's diagnostics
            res = xcalib.calibrate(list(case.frames), case.intrinsics_given, config)
    except Exception as exc:  # an exception is a finding too (bad input must not raise)
        return {"condition": name, "seed": seed, "success": False, "exception": repr(exc),
                "message": f"exception: {exc!r}", "time_s": time.perf_counter() - t0}
    rec = {"condition": name, "seed": seed, "success": bool(res.success), "message": res.message,
           "time_s": time.perf_counter() - t0, "n_pairs": res.n_pairs, "objects_seen": case.objects_seen,
           "true_pairs": case.true_pairs, "identifiable": case.identifiable}
    if res.success:
        from xcalib.calib.pose import Pose
        from xcalib.calib.uncertainty import bound95

        rot, tr = res.pose_error(case.T_cam_lidar)
        rs, ts = float(np.linalg.norm(res.rotation_std_deg)), float(np.linalg.norm(res.translation_std_m))
        delta = Pose.parse(res.extrinsics).delta(Pose.parse(case.T_cam_lidar))
        sd = np.concatenate([res.rotation_std_deg, res.translation_std_m])
        rec["z_axes"] = [float(v) for v in np.abs(delta) / np.maximum(sd, 1e-12)]
        rec["sigma_axes"] = [float(v) for v in sd]
        rec["sigma_parts"] = {k: v for k, v in res.diagnostics.uncertainty.__dict__.items() if k != "box_model"}
        rec["within_95"] = bool(rot <= bound95(res.rotation_std_deg) and tr <= bound95(res.translation_std_m))
        rec.update(rot_deg=rot, trans_m=tr, rot_sigma_deg=rs, trans_sigma_m=ts,
                   wrong=bool(rot > WRONG_ROT_DEG or tr > WRONG_TRANS_M),
                   rot_within_2sigma=bool(rot <= 2 * rs), trans_within_2sigma=bool(tr <= 2 * ts))
        rec["within_2sigma"] = rec["rot_within_2sigma"] and rec["trans_within_2sigma"]
    if not res.success and res.diagnostics.refused_T is not None:  # what a refused pose would have promised
        from xcalib.calib.pose import Pose

        delta = Pose.parse(np.asarray(res.diagnostics.refused_T)).delta(Pose.parse(case.T_cam_lidar))
        rec.update(refusal=res.diagnostics.refusal, refused_delta=[float(v) for v in delta],
                   sigma_axes=[float(v) for v in np.concatenate([res.rotation_std_deg, res.translation_std_m])],
                   sigma_parts={k: v for k, v in res.diagnostics.uncertainty.__dict__.items() if k != "box_model"})
    intr = getattr(res, "intrinsics", None)
    if opts is not None:
        sc = res.diagnostics.selfcal
        rec.update(focal_estimated=sc.focal_estimated, focal_scale_std=sc.focal_scale_std,
                   time_offset_source=sc.time_offset_source, time_offset_std_s=sc.time_offset_std_s)
    if intr is not None and res.success:
        rec["focal_ratio_est_to_true"] = float(intr.fx / case.intrinsics_true.fx)
    dt = getattr(res, "time_offset_s", None)
    if dt is not None and res.success and np.isfinite(dt):
        rec["time_offset_error_s"] = float(dt - case.time_offset_s)
    return rec


def _median(v):
    return float(np.median(v)) if len(v) else None


def _axis_cov(ok: list[dict], axes: slice) -> float | None:
    z = [v for r in ok if "z_axes" in r for v in r["z_axes"][axes]]
    return float(np.mean(np.asarray(z) <= 2)) if z else None


def summarise(name: str, recs: list[dict]) -> dict:
    """One table row from the per-site records of a condition."""
    from xcalib.data.synth.realism import REALISM_CONDITIONS

    ok = [r for r in recs if r["success"]]
    wrong = [r for r in ok if r["wrong"]]
    return {
        "condition": name, "description": REALISM_CONDITIONS[name.removesuffix(SELFCAL_SUFFIX)].description
        + (" [refine_intrinsics / time_offset estimated]" if name.endswith(SELFCAL_SUFFIX) else ""), "n": len(recs),
        "success": len(ok), "success_rate": len(ok) / max(len(recs), 1), "wrong_successes": len(wrong),
        # the calibrator refuses poses resting on < 4 distinct objects (decision.MIN_OBJECTS): the
        # success rate over the sites whose frames show 4+ objects to both sensors
        "n_4plus_objects": len(four := [r for r in recs if r.get("objects_seen", 0) >= 4]),
        "success_4plus_objects": sum(r["success"] for r in four),
        "rot_deg_median": _median([r["rot_deg"] for r in ok]), "trans_m_median": _median([r["trans_m"] for r in ok]),
        "coverage_2sigma": float(np.mean([r["within_2sigma"] for r in ok])) if ok else None,
        "coverage_2sigma_rot": float(np.mean([r["rot_within_2sigma"] for r in ok])) if ok else None,
        "coverage_2sigma_trans": float(np.mean([r["trans_within_2sigma"] for r in ok])) if ok else None,
        "coverage_95": float(np.mean([r["within_95"] for r in ok if "within_95" in r])) if any("within_95" in r for r in ok) else None,
        "coverage_axis_rot": _axis_cov(ok, slice(0, 3)), "coverage_axis_trans": _axis_cov(ok, slice(3, 6)),
        "wrong_rot_deg_median": _median([r["rot_deg"] for r in wrong]),
        "wrong_trans_m_median": _median([r["trans_m"] for r in wrong]),
        "wrong_rot_sigma_deg_median": _median([r["rot_sigma_deg"] for r in wrong]),
        "wrong_trans_sigma_m_median": _median([r["trans_sigma_m"] for r in wrong]),
        "exceptions": sum(1 for r in recs if "exception" in r),
        # sites still identifiable under this condition (>= 3 objects, >= 20 true pairs seen by both)
        "n_identifiable": sum(1 for r in recs if r.get("identifiable", True)),
        "time_s_median": _median([r["time_s"] for r in recs]),
        "focal_rel_err_median": _median([abs(r["focal_ratio_est_to_true"] - 1) for r in ok
                                         if "focal_ratio_est_to_true" in r]),
        "time_offset_abs_err_median_s": _median([abs(r["time_offset_error_s"]) for r in ok
                                                 if "time_offset_error_s" in r]),
        "per_site": recs,
    }


def print_table(rows: list[dict]) -> None:
    f = (lambda v, d=3: "-" if v is None else f"{v:.{d}f}")
    print(f"\n{'condition':>34} {'n':>3} {'success':>8} {'4+ obj':>7} {'wrong':>5} {'rot med':>8} {'trans med':>9} "
          f"{'2sig cov':>8} {'95% cov':>7} {'axis cov r/t':>12} {'wrong: rot/trans med':>21} {'time med':>8}")
    for r in rows:
        wr = "-" if not r["wrong_successes"] else f"{r['wrong_rot_deg_median']:.2f}/{r['wrong_trans_m_median']:.2f}"
        four = f"{r['success_4plus_objects']}/{r['n_4plus_objects']}"
        print(f"{r['condition']:>34} {r['n']:>3} {r['success']:>3} ({r['success_rate'] * 100:>3.0f}%) {four:>7} "
              f"{r['wrong_successes']:>4} {f(r['rot_deg_median']):>8} {f(r['trans_m_median']):>9} "
              f"{f(r['coverage_2sigma'], 2):>8} {f(r.get('coverage_95'), 2):>7} "
              f"{f(r.get('coverage_axis_rot'), 2) + '/' + f(r.get('coverage_axis_trans'), 2):>12} {wr:>21} "
              f"{f(r['time_s_median'], 2):>7}s")


def _git_head() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def main(argv=None) -> int:
    from xcalib.data.synth.realism import REALISM_CONDITIONS, identifiable_site_seeds

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sites", type=int, default=20)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--conditions", default="all", help="comma-separated names (default: all registered)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes")
    ap.add_argument("--label", default="current", help="name of this run in the JSON (e.g. before, after)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--selfcal", action="store_true", help="add a '+selfcal' row per condition (issue 13)")
    ap.add_argument("--refine-intrinsics", default="auto", help="CalibConfig.refine_intrinsics of the +selfcal rows")
    ap.add_argument("--time-offset", default="auto", help="CalibConfig.time_offset of the +selfcal rows")
    ap.add_argument("--box-noise-px", type=float, default=None,
                    help="2D box noise (px, 1-sigma) of every condition instead of its own (e.g. 4: a real detector's)")
    args = ap.parse_args(argv)
    names = list(REALISM_CONDITIONS) if args.conditions == "all" else [c.strip() for c in args.conditions.split(",")]
    unknown = [n for n in names if n not in REALISM_CONDITIONS]
    if unknown:
        ap.error(f"unknown condition(s) {unknown}; registered: {', '.join(REALISM_CONDITIONS)}")
    seeds = identifiable_site_seeds(args.sites, args.frames)
    tasks = [(n, s, args.frames, None, args.box_noise_px) for n in names for s in seeds]
    if args.selfcal:
        tasks += [(n, s, args.frames, (args.refine_intrinsics, args.time_offset), args.box_noise_px)
                  for n in names for s in seeds]
        names = [x for n in names for x in (n, n + SELFCAL_SUFFIX)]
    t0 = time.perf_counter()
    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as ex:
            recs = list(ex.map(run_case, tasks, chunksize=1))
    else:
        recs = [run_case(t) for t in tasks]
    rows = [summarise(n, [r for r in recs if r["condition"] == n]) for n in names]
    print(f"Realism suite: {len(seeds)} identifiable roadside sites x {args.frames} frames per condition; "
          f"xcalib.calibrate(frames, given intrinsics), no initial guess.\nwrong = success off by > 1 deg or "
          f"> 0.5 m; 2sig cov = share of successes with rot err <= 2|rot sigma| and trans err <= 2|trans sigma|")
    print_table(rows)
    from _provenance import provenance

    run = {"label": args.label, "git_head": _git_head(), "provenance": provenance(argv), "machine": machine_info(), "jobs": args.jobs,
           "frames": args.frames, "box_noise_px": args.box_noise_px, "site_seeds": seeds, "wall_s": time.perf_counter() - t0,
           "command": "benchmarks/bench_calibration_realism.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "conditions": rows}
    runs = load_runs(args.out)
    runs[args.label] = run
    write_runs(args.out, runs)
    print(f"\nwrote {args.out} and {detail_path(args.out).name} (run {args.label!r})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
