"""The reported sigma rebuilt from the parts stored with realism runs (issue 25, session 9).

Every success record of ``benchmarks/results/calibration_realism.json`` keeps its sigma's parts
(``sigma_parts``: Jacobian, object-clustered CR2, occlusion and outline shifts with their noise,
floor, the objects' own-outline sigma) and its per-axis error (``z_axes`` x ``sigma_axes``); the
poses do not depend on how the parts are combined, so a change of the combination is measured
exactly on the stored runs (a re-run of ``detector_outline`` / ``detector_all`` at the changed code
gave the rebuilt sigmas to 2e-16).

    PYTHONPATH=src python scripts/sigma_parts.py table s8_cr2_20sites [--z 1 1.96]
    PYTHONPATH=src python scripts/sigma_parts.py parts s8_cr2_20sites

``table``: per condition the share of axes whose |error| / sigma exceeds the median expected for
them (0.5 = right; the Bell-McCaffrey degrees of freedom ``clusters_dof`` where the CR2 part is the
largest, the normal 0.674 elsewhere) and the 95 % coverage (``uncertainty.bound95``), with the
model shifts counted beyond ``z`` of their noise sigmas (``uncertainty.excess``). ``parts``: per
condition how many axes each part is the largest on.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "calibration_realism.json"
CONDITIONS = ("clean", "detector_misses", "detector_scores", "detector_merge", "detector_outline",
              "detector_truncation", "detector_all")


def _a(v):
    return None if v is None else np.asarray(v, dtype=np.float64)


def rebuild(parts: dict, z: float) -> np.ndarray:
    """The reported 6-vector sigma (deg, m) from stored ``parts``, shifts counted beyond ``z`` noise sigmas."""
    from xcalib.calib.uncertainty import combine, excess

    fl, sc = _a(parts["floor"]), _a(parts["selfcal"])
    floor = None if fl is None and sc is None else np.sqrt((0 if fl is None else fl ** 2) + (0 if sc is None else sc ** 2))
    outl = None if parts["outline"] is None else excess(parts["outline"], _a(parts["outline_noise"]), z)
    r, t = combine(_a(parts["jacobian"]), _a(parts["halves"]), excess(parts["occlusion"], _a(parts["occlusion_noise"]), z),
                   _a(parts["jackknife"]), _a(parts["objects"]), floor, _a(parts["clusters"]), outl)
    sd = np.concatenate([r, t])
    return sd if parts.get("object_outline") is None else np.fmax(sd, _a(parts["object_outline"]))


def expected_median(rec: dict, sd: np.ndarray) -> np.ndarray:
    """Per axis the median of |error| / sigma a right sigma gives: t-based where CR2 (scaled by
    t(0.975, nu) / 1.96) is the largest part, else the normal 0.674."""
    from scipy import stats

    if not rec.get("clusters_dof"):
        return np.full(6, 0.6745)
    nu = np.clip(_a(rec["clusters_dof"]), 1.0, None)
    em = stats.t.ppf(0.75, nu) * 1.959964 / stats.t.ppf(0.975, nu)
    return np.where(_a(rec["sigma_parts"]["clusters"]) / sd > 0.9, em, 0.6745)


def table(run: dict, zs: list[float]) -> None:
    from xcalib.calib.uncertainty import bound95

    for z in zs:
        pooled_s, pooled_c, cells = [], [], []
        for cond in run["conditions"]:
            if cond["condition"] not in CONDITIONS:
                continue
            share, cov = [], []
            for rec in (r for r in cond["per_site"] if r["success"] and "sigma_parts" in r):
                err = _a(rec["z_axes"]) * _a(rec["sigma_axes"])
                sd = rebuild(rec["sigma_parts"], z)
                share += list(err / sd > expected_median(rec, sd))
                cov.append(bool(np.linalg.norm(err[:3]) <= bound95(sd[:3]) and np.linalg.norm(err[3:]) <= bound95(sd[3:])))
            pooled_s += share
            pooled_c += cov
            cells.append(f"{cond['condition'].removeprefix('detector_')} {np.mean(share):.2f}/{np.mean(cov):.2f} (n={len(cov)})")
        print(f"z={z:g}: " + " | ".join(cells) + f" || together {np.mean(pooled_s):.2f}/{np.mean(pooled_c):.3f}")


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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("what", choices=("table", "parts"))
    ap.add_argument("label", help="a run of calibration_realism.json whose records keep sigma_parts")
    ap.add_argument("--z", type=float, nargs="+", default=[1.0, 1.959964])
    args = ap.parse_args(argv)
    run = json.loads(RESULTS.read_text())["runs"][args.label]
    table(run, args.z) if args.what == "table" else largest_parts(run)
    return 0


if __name__ == "__main__":
    sys.exit(main())
