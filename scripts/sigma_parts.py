"""The reported sigma rebuilt from the parts stored with realism runs (issue 25, session 9).

Every success record of ``benchmarks/results/calibration_realism.json`` keeps its sigma's parts
(``sigma_parts``: Jacobian, object-clustered CR2, occlusion and outline shifts with their noise,
floor, the objects' own-outline sigma) and its per-axis error (``z_axes`` x ``sigma_axes``); the
poses do not depend on how the parts are combined, so a change of the combination is measured
exactly on the stored runs (a re-run of ``detector_outline`` / ``detector_all`` at the changed code
gave the rebuilt sigmas to 2e-16).

    PYTHONPATH=src python scripts/sigma_parts.py table s8_cr2_20sites [--z 1 1.96] [--bound old|new|rho1|rho0]
    PYTHONPATH=src python scripts/sigma_parts.py parts s8_cr2_20sites
    PYTHONPATH=src python scripts/sigma_parts.py bound s8_cr2_20sites [--z 1.96]

``table``: per condition the share of axes whose |error| / sigma exceeds the median expected for
them (0.5 = right; the Bell-McCaffrey degrees of freedom ``clusters_dof`` where the CR2 part is the
largest, the normal 0.674 elsewhere) and the 95 % coverage (``uncertainty.bound95``), with the
model shifts counted beyond ``z`` of their noise sigmas (``uncertainty.excess``). ``parts``: per
condition how many axes each part is the largest on.

``--bound`` (session 10): which 95 % bound ``table`` judges: ``old`` the per-axis sigma (each CR2 axis
stretched by t(0.975, nu) / 1.96) in a chi-square bound; ``new`` the raw (unstretched) variances in
the F bound with the Satterthwaite degrees of freedom of their trace (``uncertainty.bound_parts``: the
cross-axis dof matrix where the record keeps it, else the per-axis dofs taken as fully correlated,
which is ``rho1``); ``rho0`` the per-axis dofs taken as independent (the narrowest). ``bound``: per
condition the 95 % coverage under each, the per-axis 2-sigma coverage, and which stored refusals
(``uncertain``, ``too_few_objects``) each would deliver, right or wrong (> 1 deg or > 0.5 m).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "calibration_realism.json"
SHIFT_NOISE_Z = 1.959964  # uncertainty.SHIFT_NOISE_Z (the hidden-edge shift's threshold, not the --z being studied)
CONDITIONS = ("clean", "detector_misses", "detector_scores", "detector_merge", "detector_outline",
              "detector_truncation", "detector_all")


def _a(v):
    return None if v is None else np.asarray(v, dtype=np.float64)


def rebuild(parts: dict, z: float, cr2: str = "beyond_model") -> np.ndarray:
    """The reported 6-vector sigma (deg, m) from stored ``parts``, shifts counted beyond ``z`` noise sigmas, as
    the current code combines them (``uncertainty.estimate``; the CR2 part through ``clustered_part`` against the
    Jacobian and the centre floor, the hidden-edge shift, the centre floor, the objects' outlines, the focal
    choice's part). ``cr2="full"``: the CR2 part with its whole Student's t stretch, as runs before session 13
    combined it (the stored ``clusters`` as they are)."""
    from xcalib.calib.uncertainty import clustered_part, combine, excess

    fl, sc = _a(parts.get("floor")), _a(parts.get("selfcal"))
    floor = None if fl is None and sc is None else np.sqrt((0 if fl is None else fl ** 2) + (0 if sc is None else sc ** 2))
    outl = None if parts.get("outline") is None else excess(parts["outline"], _a(parts.get("outline_noise")), z)
    jac, cfloor = _a(parts["jacobian"]), _a(parts.get("centre_floor"))
    clus = _a(parts["clusters"]) if cr2 == "full" else \
        clustered_part(_a(parts["clusters"]), _a(parts.get("clusters_dof")), jac if cfloor is None else np.fmax(jac, cfloor))
    r, t = combine(jac, _a(parts["halves"]), excess(parts["occlusion"], _a(parts.get("occlusion_noise")), z),
                   _a(parts["jackknife"]), _a(parts["objects"]), floor, clus, outl)
    sd = np.concatenate([r, t])
    if parts.get("hidden") is not None:  # session 10: in quadrature, beyond SHIFT_NOISE_Z of its noise
        sd = np.sqrt(sd ** 2 + excess(parts["hidden"], _a(parts.get("hidden_noise")), SHIFT_NOISE_Z) ** 2)
    sd = sd if cfloor is None else np.fmax(sd, cfloor)  # session 12: the measured centre error's floor
    sd = sd if parts.get("object_outline") is None else np.fmax(sd, _a(parts["object_outline"]))
    # the focal choice's box-model part (session 12): in quadrature, after the objects' outlines
    return sd if parts.get("focal_box_model") is None else np.sqrt(sd ** 2 + _a(parts["focal_box_model"]) ** 2)


def expected_median(rec: dict, sd: np.ndarray) -> np.ndarray:
    """Per axis the median of |error| / sigma a right sigma gives: t-based where CR2 (scaled by
    t(0.975, nu) / 1.96) is the largest part, else the normal 0.674."""
    from scipy import stats

    dof = rec.get("clusters_dof") or rec["sigma_parts"].get("clusters_dof")  # top level: the s8 wrapper's records
    if not dof:
        return np.full(6, 0.6745)
    nu = np.clip(_a(dof), 1.0, None)
    em = stats.t.ppf(0.75, nu) * 1.959964 / stats.t.ppf(0.975, nu)
    return np.where(_a(rec["sigma_parts"]["clusters"]) / sd > 0.9, em, 0.6745)


def bound_inputs(rec: dict, z: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(raw 6-vector variance of the reported sigma with the CR2 part unstretched, the part of it the
    CR2 estimate is, the CR2 per-axis dofs) rebuilt from a record's stored parts; the dofs are the
    objects - 1 where the record predates ``clusters_dof`` (its clustered part was the jackknife)."""
    from scipy.special import stdtrit

    parts = dict(rec["sigma_parts"])
    if parts.get("clusters") is None:
        return rebuild(parts, z) ** 2, np.zeros(6), np.full(6, np.inf)
    dof = rec.get("clusters_dof") or parts.get("clusters_dof")
    nu = np.clip(_a(dof), 1.0, None) if dof else np.full(6, max(float(parts.get("n_objects") or 2) - 1.0, 1.0))
    raw = _a(parts["clusters"]) * 1.959964 / stdtrit(nu, 0.975)
    others = np.abs(_a(parts["jacobian"]))
    if parts.get("objects") is not None:
        others = np.fmax(others, np.abs(_a(parts["objects"])))
    oo = None if parts.get("object_outline") is None else _a(parts["object_outline"])
    parts.update(clusters=list(raw), clusters_dof=None, object_outline=None)  # raw: no clustered_part stretch
    var = rebuild(parts, z) ** 2
    rand = np.where(raw >= others, raw ** 2, 0.0)
    if oo is not None:
        rand = np.where(oo ** 2 > var, 0.0, rand)
        var = np.fmax(var, oo ** 2)
    return var, rand, nu


def bounds(rec: dict, z: float, kind: str, cr2: str = "beyond_model") -> tuple[float, float]:
    """(rotation deg, translation m) 95 % bound of a record under ``kind`` (old | new | rho1 | rho0); ``cr2`` as
    ``rebuild``'s (the ``old`` kind)."""
    from xcalib.calib.uncertainty import bound95

    if kind == "old":
        sd = rebuild(rec["sigma_parts"], z, cr2)
        return bound95(sd[:3]), bound95(sd[3:])
    from xcalib.calib.uncertainty import bound_dof

    var, rand, nu = bound_inputs(rec, z)
    parts = rec["sigma_parts"]
    exact = kind == "new" and parts.get("clusters_dof_cross") is not None
    if exact:
        cross, corr = _a(parts["clusters_dof_cross"]), _a(parts["clusters_corr"])
    elif kind == "rho0":  # the axes' variance estimates independent
        cross, corr = np.diag(1.0 / nu), np.eye(6)
    else:  # new / rho1 without the stored cross-axis dofs: fully correlated
        cross, corr = 1.0 / np.sqrt(np.outer(nu, nu)), np.eye(6)
    out = []
    for blk in (slice(0, 3), slice(3, 6)):
        v, e = var[blk], rand[blk]
        if not np.all(np.isfinite(v)):
            out.append(float("inf"))
            continue
        se = np.sqrt(e)
        cov = np.diag(v - e) + np.outer(se, se) * corr[blk, blk]
        out.append(bound95(None, cov=cov, dof=bound_dof(v, e, cross[blk, blk])))
    return out[0], out[1]


def table(run: dict, zs: list[float], kind: str = "old", cr2: str = "beyond_model") -> None:
    for z in zs:
        pooled_s, pooled_c, cells = [], [], []
        for cond in run["conditions"]:
            if cond["condition"] not in CONDITIONS:
                continue
            share, cov = [], []
            for rec in (r for r in cond["per_site"] if r["success"] and "sigma_parts" in r):
                err = _a(rec["z_axes"]) * _a(rec["sigma_axes"])
                sd = rebuild(rec["sigma_parts"], z, cr2)
                share += list(err / sd > expected_median(rec, sd))
                br, bt = bounds(rec, z, kind, cr2)
                cov.append(bool(np.linalg.norm(err[:3]) <= br and np.linalg.norm(err[3:]) <= bt))
            pooled_s += share
            pooled_c += cov
            cells.append(f"{cond['condition'].removeprefix('detector_')} {np.mean(share):.2f}/{np.mean(cov):.2f} (n={len(cov)})")
        print(f"z={z:g}: " + " | ".join(cells) + f" || together {np.mean(pooled_s):.2f}/{np.mean(pooled_c):.3f}")


def error6(rec: dict) -> np.ndarray | None:
    """A record's 6-vector pose error (deg, m): a success's ``z x sigma``, a refusal's ``refused_delta``."""
    if rec["success"]:
        return _a(rec["z_axes"]) * _a(rec["sigma_axes"])
    return None if rec.get("refused_delta") is None else np.abs(_a(rec["refused_delta"]))


def bound_report(run: dict, z: float, limits=(2.0, 1.2), wrong=(1.0, 0.5), cr2: str = "beyond_model") -> None:
    """Per condition, per bound kind: the 95 % coverage of the successes, the per-axis 2-sigma coverage,
    successes the bound would refuse, and stored ``uncertain`` / ``too_few_objects`` refusals it
    would deliver (right / wrong)."""
    kinds = ("old", "new", "rho0")
    tot = {k: [0, 0, 0, 0, 0] for k in kinds}
    for cond in run["conditions"]:
        recs = [r for r in cond["per_site"] if "sigma_parts" in r]
        cells = []
        for k in kinds:
            cov, lost, gained_ok, gained_bad = [], 0, 0, 0
            for rec in recs:
                e = error6(rec)
                if e is None:
                    continue
                br, bt = bounds(rec, z, k, cr2)
                passes = br <= limits[0] and bt <= limits[1]
                bad = bool(np.linalg.norm(e[:3]) > wrong[0] or np.linalg.norm(e[3:]) > wrong[1])
                if rec["success"]:
                    cov.append(bool(np.linalg.norm(e[:3]) <= br and np.linalg.norm(e[3:]) <= bt))
                    lost += not passes
                elif rec.get("refusal") in ("uncertain", "too_few_objects") and passes:
                    gained_ok += not bad
                    gained_bad += bad
            t = tot[k]
            t[0] += sum(cov)
            t[1] += len(cov)
            t[2] += lost
            t[3] += gained_ok
            t[4] += gained_bad
            cells.append(f"{k} {np.mean(cov) if cov else float('nan'):.2f}" + (f" -{lost}" if lost else "")
                         + (f" +{gained_ok}" if gained_ok else "") + (f" WRONG+{gained_bad}" if gained_bad else ""))
        axes = [np.abs(error6(r)) <= 1.959964 * rebuild(r["sigma_parts"], z, cr2) for r in recs if r["success"]]
        ax = f"{np.mean(axes):.3f}" if axes else "-"
        n_ref = sum(1 for r in recs if r.get("refusal") in ("uncertain", "too_few_objects"))
        print(f"{cond['condition']:26s} n={sum(r['success'] for r in recs):2d} axis2sd {ax} refusals(bound) {n_ref:2d} | "
              + " | ".join(cells))
    print("together: " + " | ".join(f"{k} {t[0]}/{t[1]} = {t[0] / max(t[1], 1):.3f}, successes refused {t[2]}, "
                                     f"refusals delivered right {t[3]} wrong {t[4]}" for k, t in tot.items()))


def largest_parts(run: dict) -> None:
    from xcalib.calib.uncertainty import excess

    for cond in run["conditions"]:
        if cond["condition"] not in CONDITIONS:
            continue
        count: dict[str, int] = {}
        for rec in (r for r in cond["per_site"] if r["success"] and "sigma_parts" in r):
            p = rec["sigma_parts"]
            cand = {"clusters": _a(p["clusters"]), "jacobian": _a(p["jacobian"]),
                    "occlusion excess": excess(p["occlusion"], _a(p["occlusion_noise"])),
                    "outline excess": np.zeros(6) if p["outline"] is None else excess(p["outline"], _a(p["outline_noise"])),
                    "floor": np.zeros(6) if p["floor"] is None else _a(p["floor"]),
                    "object outline": np.zeros(6) if p["object_outline"] is None else _a(p["object_outline"])}
            names = list(cand)
            top = np.argmax(np.stack([np.abs(cand[k]) for k in names]), axis=0)
            for i in top:
                count[names[i]] = count.get(names[i], 0) + 1
        print(f"{cond['condition']:22s} " + ", ".join(f"{k} {v}" for k, v in sorted(count.items(), key=lambda kv: -kv[1])))


def load_results() -> dict:
    """``{"runs": ...}`` of ``RESULTS`` with each per-site record's ``sigma_parts`` joined back from its side
    file ``calibration_realism_detail.json.gz`` (``bench_calibration_realism.load_runs``)."""
    bench_dir = str(RESULTS.parents[1])
    if bench_dir not in sys.path:
        sys.path.insert(0, bench_dir)
    import bench_calibration_realism

    return {"runs": bench_calibration_realism.load_runs(RESULTS)}


def load_run(label: str) -> dict:
    """A run of ``calibration_realism.json`` by label, or records one per line in a ``.jsonl`` file
    (``bench_calibration_realism.run_case``'s records, e.g. written one by one by a wrapper)."""
    if not label.endswith(".jsonl"):
        return load_results()["runs"][label]
    by: dict[str, list] = {}
    for line in Path(label).read_text().splitlines():
        if line.strip():
            rec = json.loads(line)
            by.setdefault(rec["condition"], []).append(rec)
    return {"conditions": [{"condition": c, "per_site": recs} for c, recs in by.items()]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("table", "parts", "bound"))
    ap.add_argument("label", help="a run of calibration_realism.json whose records keep sigma_parts (or a .jsonl of records)")
    ap.add_argument("--z", type=float, nargs="+", default=[1.0, 1.959964])
    ap.add_argument("--bound", choices=("old", "new", "rho1", "rho0"), default="old",
                    help="the 95 %% bound ``table`` judges (see the module docstring)")
    ap.add_argument("--cr2", choices=("beyond_model", "full"), default="beyond_model",
                    help="how the CR2 part counts its t stretch: beyond the model sigmas (session 13, the code's) or "
                         "whole (before)")
    args = ap.parse_args(argv)
    run = load_run(args.label)
    if args.what == "table":
        table(run, args.z, args.bound, args.cr2)
    elif args.what == "bound":
        bound_report(run, args.z[-1], cr2=args.cr2)
    else:
        largest_parts(run)
    return 0


if __name__ == "__main__":
    sys.exit(main())
