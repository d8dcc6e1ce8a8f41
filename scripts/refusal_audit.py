"""Which check refuses correct poses? An audit of the refusals stored with realism runs (issue 25).

Every refusal record of ``benchmarks/results/calibration_realism.json`` (since session 5) keeps the
refusal's code (``refusal``) and the refused pose's error against the truth (``refused_delta``:
rotation vector in deg, translation in m). This script tabulates, per condition (the latest stored
run that has per-site records, or the runs named with ``--labels``) and per refusal code, how many
refused poses were right -- within 0.3 deg / 0.2 m (``strict``) and within 1 deg / 0.5 m (``line``,
the benchmarks' wrong-pose line) -- and how many wrong.

    python scripts/refusal_audit.py table [--labels s8_cr2_20sites,s9_sigma_outline_all] [--sites]
    python scripts/refusal_audit.py pairs [--labels ...]

``table``: the per-condition table and the totals per code (``--sites``: the site seeds too).
``pairs``: for every right refusal (within the line) the verdicts that the same site got under the
wrong-model conditions stored (principal point, focal length, time offset): a check that refuses a
right pose at a site where it is also what refuses the same site's wrong-model pose is the data's
limit there, not a weak check.

Session 14 (issue 25), from the records that keep their sigma parts (every distinct record of every run,
refused and delivered alike; a pose is wrong beyond 1 deg / 0.5 m)::

    python scripts/refusal_audit.py stops [--labels ...]
    python scripts/refusal_audit.py dominance --labels s13_final
    python scripts/refusal_audit.py selection --labels s13_final

``stops``: per refusal code, the right and the wrong poses it refused, and for each wrong pose which of the
checks that can be rebuilt from the stored parts would stop it too (``data``: the verdict's data sigma
beyond ``max_rot_std_deg`` / ``max_trans_std_m``; ``bound``: the reported 95 % bound beyond
``max_rot_bound_deg`` / ``max_trans_bound_m``; ``objects``: fewer than ``MIN_OBJECTS`` objects; a code's own check is not counted): a code
whose wrong poses all have another stop refuses right poses for nothing the others do not (the misfit
checks cannot be rebuilt, so a wrong pose a misfit check stopped may have another stop all the same).
``dominance``: for each right refusal of the named runs, the stored wrong poses whose every statistic the
sigma checks read (objects, reported 95 % bound, data sigma, data sigma with the occlusion shift beyond
its noise) is no weaker: no rule on those statistics alone delivers the right pose and not them.
``selection``: per condition, |error| / reported sigma per axis over the successes, the right refusals
and every pose: 2-sigma coverage and the 95th percentile over 1.96 (the factor by which the sigma would
have to shrink for a 95 % coverage).
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "calibration_realism.json"


def load_runs(path: Path = RESULTS) -> dict:
    """The runs of a realism results file, each per-site record's ``sigma_parts`` joined back from its
    side file (``<stem>_detail.json.gz``; ``bench_calibration_realism.load_runs``)."""
    bench_dir = str(Path(__file__).resolve().parents[1] / "benchmarks")
    if bench_dir not in sys.path:
        sys.path.insert(0, bench_dir)
    import bench_calibration_realism

    return bench_calibration_realism.load_runs(Path(path))


STRICT = (0.3, 0.2)
LINE = (1.0, 0.5)
#: conditions whose given camera model is wrong (a success there is off by the error it was given)
WRONG_MODEL = ("principal_point", "focal", "time_offset")
#: the rebuildable check (``stops``) that each of these refusal codes is itself
OWN_CHECK = {"poorly_constrained": "data", "few_objects": "objects", "uncertain": "bound", "too_few_objects": "bound"}
#: the first stored realism run whose refusal records carry the code and the refused pose
SINCE = "merged_0.6.0_8sites"


def refused_error(rec: dict) -> tuple[float, float] | None:
    """(rotation deg, translation m) of a refused pose against the truth; None when not stored."""
    d = rec.get("refused_delta")
    if d is None:
        return None
    return float(np.linalg.norm(d[:3])), float(np.linalg.norm(d[3:]))


def _within(err: tuple[float, float], lim: tuple[float, float]) -> bool:
    return err[0] <= lim[0] and err[1] <= lim[1]


def latest_records(runs: dict, labels: list[str] | None = None,
                   since: str | None = None) -> dict[str, tuple[str, list[dict]]]:
    """Condition (with ``@Npx`` for a ``--box-noise-px`` run) -> (label, per-site records) of the
    last run in file order that stored per-site records for it (only ``labels`` when given; only
    the runs from ``since`` on in file order when given)."""
    out: dict[str, tuple[str, list[dict]]] = {}
    started = since is None or since not in runs
    for label, run in runs.items():
        started = started or label == since
        if not started or (labels and label not in labels):
            continue
        noise = run.get("box_noise_px")
        suffix = "" if noise in (None, "None") else f"@{float(noise):g}px"
        for row in run.get("conditions", []):
            if row.get("per_site"):
                out[row["condition"] + suffix] = (label, row["per_site"])
    return out


def audit(records: list[dict]) -> dict[str, dict]:
    """Per refusal code: counts ``strict`` (right within 0.3 deg / 0.2 m), ``line`` (within 1 deg /
    0.5 m), ``wrong`` (beyond) and ``unknown`` (no refused pose stored), and the sites as
    (seed, rot, trans). Successes are left out."""
    out: dict[str, dict] = defaultdict(lambda: {"strict": 0, "line": 0, "wrong": 0, "unknown": 0, "sites": []})
    for rec in records:
        if rec.get("success"):
            continue
        code = rec.get("refusal") or ("exception" if "exception" in rec else "not_stored")
        err = refused_error(rec)
        row = out[code]
        if err is None:
            row["unknown"] += 1
            continue
        row["strict"] += _within(err, STRICT)
        row["line"] += _within(err, LINE)
        row["wrong"] += not _within(err, LINE)
        row["sites"].append((rec.get("seed"), round(err[0], 3), round(err[1], 3)))
    return dict(out)


def totals(per_condition: dict[str, dict[str, dict]]) -> dict[str, dict[str, int]]:
    """Per refusal code, the counts summed over the conditions."""
    out: dict[str, dict[str, int]] = defaultdict(lambda: {"strict": 0, "line": 0, "wrong": 0, "unknown": 0})
    for codes in per_condition.values():
        for code, row in codes.items():
            for k in ("strict", "line", "wrong", "unknown"):
                out[code][k] += row[k]
    return dict(out)


def pairs(latest: dict[str, tuple[str, list[dict]]]) -> list[tuple[str, int, str, tuple, list]]:
    """For each right refusal (within the line) under a condition with the right camera model:
    (condition, seed, code, error, [(wrong-model condition, its verdict, its error), ...] at that site)."""
    by_site: dict[int, list[tuple[str, dict]]] = defaultdict(list)
    for cond, (_, recs) in latest.items():
        if cond.startswith(WRONG_MODEL):
            for r in recs:
                by_site[r.get("seed")].append((cond, r))
    out = []
    for cond, (_, recs) in latest.items():
        if cond.startswith(WRONG_MODEL):
            continue
        for r in recs:
            err = refused_error(r)
            if r.get("success") or err is None or not _within(err, LINE):
                continue
            other = []
            for c2, r2 in by_site.get(r.get("seed"), []):
                e2 = (r2["rot_deg"], r2["trans_m"]) if r2.get("success") else refused_error(r2)
                other.append((c2, "success" if r2.get("success") else r2.get("refusal", "?"),
                              None if e2 is None else (round(e2[0], 2), round(e2[1], 2))))
            out.append((cond, r.get("seed"), r.get("refusal", "?"), (round(err[0], 3), round(err[1], 3)), other))
    return out


def error6(rec: dict) -> np.ndarray | None:
    """The pose's 6-vector error (deg about x, y, z; m) against the truth: ``z_axes * sigma_axes`` of a
    success, ``refused_delta`` of a refusal; None when not stored."""
    if rec.get("success"):
        z, sd = rec.get("z_axes"), rec.get("sigma_axes")
        return None if z is None or sd is None else np.asarray(z, float) * np.asarray(sd, float)
    d = rec.get("refused_delta")
    return None if d is None else np.asarray(d, float)


def _norms(v) -> tuple[float, float]:
    v = np.abs(np.asarray(v, float))
    return float(np.linalg.norm(v[:3])), float(np.linalg.norm(v[3:]))


def is_wrong(err6: np.ndarray) -> bool:
    r, t = _norms(err6)
    return r > LINE[0] or t > LINE[1]


def verdict_stats(rec: dict) -> np.ndarray | None:
    """What the verdict's sigma checks read, rebuilt from a record's stored ``sigma_parts`` (None without
    them): (-objects, reported 95 % bound deg, m, data sigma norm deg, m, the same with the occlusion shift
    beyond its noise deg, m) -- smaller is stronger in every entry."""
    from types import SimpleNamespace

    from xcalib.calib.decision import data_sd_beyond_noise
    from xcalib.calib.uncertainty import bound95

    parts, sd = rec.get("sigma_parts"), rec.get("sigma_axes")
    if not parts or sd is None or parts.get("jacobian") is None or parts.get("occlusion") is None:
        return None
    keys = ("jacobian", "halves", "jackknife", "occlusion", "occlusion_noise", "frames", "selfcal")
    ns = SimpleNamespace(**{k: parts.get(k) for k in keys})
    beyond = data_sd_beyond_noise(ns)
    data = data_sd_beyond_noise(SimpleNamespace(**{**vars(ns), "occlusion_noise": None}))
    sd = np.asarray(sd, float)
    return np.array([-float(parts.get("n_objects") or 0), bound95(sd[:3]), bound95(sd[3:]), *_norms(data),
                     *_norms(beyond)])


def distinct_records(runs: dict, labels: list[str] | None = None) -> list[dict]:
    """Every per-site record with sigma parts and a stored error (of ``labels`` when given), once per
    (condition, site, verdict, error to 1e-4): re-runs of unchanged code count once. Each carries
    ``condition`` and ``run``."""
    out: dict[tuple, dict] = {}
    for label, run in runs.items():
        if labels and label not in labels:
            continue
        for row in run.get("conditions", []):
            for rec in row.get("per_site") or []:
                err = error6(rec)
                if err is None or not rec.get("sigma_parts"):
                    continue
                key = (row["condition"], rec.get("seed"), rec.get("refusal") or "success", tuple(np.round(err, 4)))
                out[key] = dict(rec, condition=row["condition"], run=label)
    return list(out.values())


def stops(records: list[dict], limits: tuple[float, float, float, float]) -> dict[str, dict]:
    """Per refusal code (``success`` for the delivered): ``right`` / ``wrong`` counts and ``wrong_sites`` as
    (condition, seed, run, [the other checks that stop it too]); ``limits`` = (max_rot_std_deg,
    max_trans_std_m, max_rot_bound_deg, max_trans_bound_m)."""
    from xcalib.calib.uncertainty import MIN_OBJECTS

    out: dict[str, dict] = defaultdict(lambda: {"right": 0, "wrong": 0, "wrong_sites": []})
    for rec in records:
        code = "success" if rec.get("success") else rec.get("refusal") or "not_stored"
        err, st = error6(rec), verdict_stats(rec)
        if not is_wrong(err):
            out[code]["right"] += 1
            continue
        out[code]["wrong"] += 1
        also = []
        if st is not None:
            also += ["data"] * bool(st[3] > limits[0] or st[4] > limits[1])
            also += ["bound"] * bool(st[1] > limits[2] or st[2] > limits[3])
            also += ["objects"] * bool(-st[0] < MIN_OBJECTS)
        also = [a for a in also if a != OWN_CHECK.get(code)]  # a code's own check is not another stop
        out[code]["wrong_sites"].append((rec["condition"], rec.get("seed"), rec["run"], also))
    return dict(out)


def dominance(targets: list[dict], records: list[dict]) -> list[tuple[dict, list[dict], list[dict]]]:
    """For each right refusal in ``targets``: (it, the wrong refused poses of ``records`` refused by the
    same code whose ``verdict_stats`` are no weaker in every entry, those refused by any code)."""
    wrong = [(r, verdict_stats(r)) for r in records if not r.get("success") and is_wrong(error6(r))]
    wrong = [(r, s) for r, s in wrong if s is not None]
    out = []
    for rec in targets:
        st = verdict_stats(rec)
        if rec.get("success") or st is None or is_wrong(error6(rec)):
            continue
        anyc = [r for r, s in wrong if np.all(s <= st + 1e-12)]
        out.append((rec, [r for r in anyc if r.get("refusal") == rec.get("refusal")], anyc))
    return out


def selection(records: list[dict]) -> dict[str, dict[str, tuple[int, float, float]]]:
    """Per condition and group (``success``, ``right_refused``, ``all``): (axes, 2-sigma coverage per axis,
    95th percentile of |error| / reported sigma over 1.96)."""
    z: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for rec in records:
        err, sd = error6(rec), rec.get("sigma_axes")
        if sd is None:
            continue
        v = list(np.abs(err) / np.asarray(sd, float))
        z[rec["condition"]]["all"] += v
        if rec.get("success"):
            z[rec["condition"]]["success"] += v
        elif not is_wrong(err):
            z[rec["condition"]]["right_refused"] += v
    return {c: {g: (len(v), float(np.mean(np.asarray(v) <= 1.959964)), float(np.quantile(v, 0.95) / 1.959964))
                for g, v in groups.items() if v} for c, groups in z.items()}


def _print_new(what: str, runs: dict, labels: list[str] | None) -> None:
    from xcalib.calib.config import CalibConfig

    cfg = CalibConfig()
    every = distinct_records(runs)
    if what == "stops":
        st = stops(distinct_records(runs, labels), (cfg.max_rot_std_deg, cfg.max_trans_std_m, cfg.max_rot_bound_deg,
                                                    cfg.max_trans_bound_m))
        print("| verdict | right | wrong | wrong poses no rebuildable other check stops |\n|---|---|---|---|")
        for code, v in sorted(st.items(), key=lambda kv: -(kv[1]["right"] + kv[1]["wrong"])):
            alone = sorted({(c, s) for c, s, _, also in v["wrong_sites"] if not also})
            print(f"| {code} | {v['right']} | {v['wrong']} | {len(alone)}: {alone} |")
    elif what == "dominance":
        for rec, same, anyc in dominance(distinct_records(runs, labels), every):
            st = verdict_stats(rec)
            names = [f"{r['condition']} {r.get('seed')} ({r['run']})" for r in same]
            print(f"{rec['condition']} {rec.get('seed')} {rec.get('refusal')}: objects {-st[0]:.0f}, bound95 "
                  f"{st[1]:.2f} deg / {st[2]:.2f} m, data sigma {st[3]:.2f} / {st[4]:.2f}, beyond noise {st[5]:.2f} / "
                  f"{st[6]:.2f}; wrong poses no weaker: same code {len(same)} {names}, any code {len(anyc)}")
    else:
        print("| condition | successes: axes, 2sd, q95/1.96 | right refused | every pose |\n|---|---|---|---|")
        for cond, g in selection(distinct_records(runs, labels)).items():
            cell = lambda k: "-" if k not in g else f"{g[k][0]}, {g[k][1]:.3f}, {g[k][2]:.2f}"
            print(f"| {cond} | {cell('success')} | {cell('right_refused')} | {cell('all')} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("table", "pairs", "stops", "dominance", "selection"))
    ap.add_argument("--labels", default="", help="comma-separated run labels (default: every run)")
    ap.add_argument("--results", type=Path, default=RESULTS)
    ap.add_argument("--since", default=SINCE, help=f"only runs from this label on (default {SINCE}: the first "
                    "run that stored refusal codes and refused poses)")
    ap.add_argument("--sites", action="store_true", help="table: list each refused site (seed, deg, m)")
    args = ap.parse_args(argv)
    runs = load_runs(args.results)
    if args.what in ("stops", "dominance", "selection"):
        _print_new(args.what, runs, [s for s in args.labels.split(",") if s] or None)
        return 0
    latest = latest_records(runs, [s for s in args.labels.split(",") if s] or None, args.since or None)
    if args.what == "pairs":
        for cond, seed, code, err, other in pairs(latest):
            print(f"{cond} site {seed}: {code} {err[0]:.3f} deg / {err[1]:.3f} m; same site: "
                  + ("; ".join(f"{c} {v} {e}" for c, v, e in other) or "no wrong-model record"))
        return 0
    per = {cond: audit(recs) for cond, (_, recs) in latest.items()}
    print("| condition | run | sites | successes | refusal: right 0.3/0.2 / right 1/0.5 / wrong / not stored |")
    print("|---|---|---|---|---|")
    for cond, (label, recs) in latest.items():
        cells = "; ".join(f"{k} {v['strict']}/{v['line']}/{v['wrong']}/{v['unknown']}" for k, v in sorted(per[cond].items()))
        print(f"| {cond} | {label} | {len(recs)} | {sum(bool(r.get('success')) for r in recs)} | {cells} |")
        if args.sites:
            for k, v in sorted(per[cond].items()):
                if v["sites"]:
                    print(f"|  | | | {k} | {v['sites']} |")
    print("\n| refusal | right 0.3 deg / 0.2 m | right 1 deg / 0.5 m | wrong | not stored |\n|---|---|---|---|---|")
    for code, v in sorted(totals(per).items(), key=lambda kv: (-kv[1]["line"], kv[0])):
        print(f"| {code} | {v['strict']} | {v['line']} | {v['wrong']} | {v['unknown']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
