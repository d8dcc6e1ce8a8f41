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
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "calibration_realism.json"
STRICT = (0.3, 0.2)
LINE = (1.0, 0.5)
#: conditions whose given camera model is wrong (a success there is off by the error it was given)
WRONG_MODEL = ("principal_point", "focal", "time_offset")
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("table", "pairs"))
    ap.add_argument("--labels", default="", help="comma-separated run labels (default: every run)")
    ap.add_argument("--results", type=Path, default=RESULTS)
    ap.add_argument("--since", default=SINCE, help=f"only runs from this label on (default {SINCE}: the first "
                    "run that stored refusal codes and refused poses)")
    ap.add_argument("--sites", action="store_true", help="table: list each refused site (seed, deg, m)")
    args = ap.parse_args(argv)
    runs = json.loads(args.results.read_text())["runs"]
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
