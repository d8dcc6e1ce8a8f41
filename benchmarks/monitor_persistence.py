"""Persistent errors of the drift monitor's per-frame evidence (issue 27): do the frames' errors
last over tens of frames?

On a drift-free stream the monitor reduces every frame to normal equations (H_k, g_k). If the
frames' errors were independent with the stated covariance, the estimate of any block of L frames
(x = -(sum H)^-1 sum g, 1-sigma from (sum H)^-1 times the block's residual variance factor) would
have a standardised variance of 1 whatever L is. Errors that persist (the same occlusion frame after
frame, an object's outline inside its box, a parked object's 3D box error) add a part that does
not average out over the frames of a block, so the ratio grows with L. Per axis (rx .. tz) and per
stream this measures:

* ``block_var_ratio``: the variance of non-overlapping L-frame block estimates about the stream's
  mean, in units of their stated variance (L = 5 .. 160);
* ``acf``: the autocorrelation of the standardised 5-frame block estimates at lags of 1 .. 16 blocks
  (5 .. 80 frames);
* ``test_var_ratio``: the monitor's own change tests (the recent L frames against the frames
  before them in the history, every ``stride`` frames): the mean of (d_i / sd_i)^2 per axis with
  the covariance the frames state (no inflation), next to the monitor's ``inflation`` at the time
  (what the default test multiplies every covariance by);
* ``per_object_share``: how much of the block variance at L = 80 is the objects' own offsets
  (each tracked object's estimate pooled over the stream, as a random effect).

    OMP_NUM_THREADS=1 PYTHONPATH=src .venv/bin/python benchmarks/monitor_persistence.py --sites 3,5,11,17 --frames 800

Streams: synthetic sites (``xcalib.data.synth``, default noise and 4 px box noise + 10 % missed 2D
boxes), A9 (16 real frames looped with 1 px jitter and 10 % dropped boxes), PandaSet 002 (three
draws of projected 2D boxes, looped) and KITTI (6 frames, looped) as in ``bench_monitor.py``. The
looped real sets repeat the same frames every pass: their errors persist by construction (an
autocorrelation of ~1 at the loop's period), which is what they say about a test that assumes
independent frames.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))

BLOCKS = (5, 10, 20, 40, 80, 160)
TEST_LENGTHS = (20, 40, 80)
LAGS = tuple(range(1, 17))
AXES6 = ("rx", "ry", "rz", "tx", "ty", "tz")
PRIOR_INFO = np.diag(1.0 / np.array([np.radians(0.1)] * 3 + [0.05] * 3) ** 2)


def collect(cal, frames, config=None, lin_from: tuple[int, np.ndarray] | None = None) -> dict:
    """Run a fresh monitor that cannot alarm (``false_alarm_rate`` 1e-12 unless ``config`` is given) over
    ``frames``; per frame its normal equations and the per-object shares; the monitor's inflation at
    every decision. ``threshold``: the test threshold of the default settings (or of ``config``): the
    one the replayed variants are held to, never the recording monitor's own. ``lin_from`` = (k, x):
    frames from the k-th on are matched and linearised at the pose change x (rad / m; e.g. an injected
    step's truth) instead of the calibration (``step_recovery`` then shows what the linearisation
    point costs)."""
    from xcalib.monitor import Monitor, MonitorConfig

    # no alarm may reset the history (the statistics below do not depend on the threshold)
    mon = Monitor(cal, config or MonitorConfig(latch=True, false_alarm_rate=1e-12))
    cm = next(iter(mon.cameras.values()))
    cm.keep_edges = True  # the unshaped residual rows too (``replay(iterate=)``)
    H, g, c, nres, objs, infl, rows, edges = [], [], [], [], [], [], [], []
    t0 = time.process_time()
    n = 0
    for f in frames:
        if lin_from is not None and n == lin_from[0]:
            cm.x_lin = np.array(lin_from[1], dtype=np.float64)
        n += 1
        sts = mon.update(f)
        q = cm.recs[-1]
        H.append(np.array(q.H))
        g.append(np.array(q.g))
        c.append(float(q.c))
        nres.append(int(q.n_res))
        rows.append(q.row.copy())
        edges.append(q.edges)
        objs.append((None if q.obj is None else np.array(q.obj), None if q.obj_H is None else np.array(q.obj_H),
                     None if q.obj_g is None else np.array(q.obj_g)))
        if sts:
            infl.append(float(cm.inflation))
    return {"H": np.array(H), "g": np.array(g), "c": np.array(c), "n_res": np.array(nres), "objects": objs,
            "inflation": infl, "alarms": len(cm.events), "rows": np.array(rows).reshape(-1, 46), "edges": edges,
            "occlusion": (cm.occlusion.tau, cm.occlusion.slope) if cm.occlusion is not None else (np.inf, 1.0),
            "threshold": float((config or MonitorConfig()).threshold),
            "cov_cal": np.array(cm.cov_cal), "cpu_ms": 1e3 * (time.process_time() - t0) / max(n, 1)}


def _fit(Hs, gs, cs, ns, cond_max: float = 1e12):
    """x, stated covariance (with the residual variance factor, as ``_Sums.fit``), or None."""
    try:
        Hi = np.linalg.inv(Hs)
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(Hi)) or np.linalg.cond(Hs) > cond_max:
        return None
    x = -Hi @ gs
    s2 = max(float(cs + x @ gs) / max(ns - 6, 1), 1.0)
    return x, Hi * s2


def block_estimates(d: dict, L: int) -> tuple[np.ndarray, np.ndarray]:
    """Non-overlapping L-frame blocks: estimates [B,6] and stated 1-sigma [B,6]."""
    X, S = [], []
    for a in range(0, len(d["g"]) - L + 1, L):
        f = _fit(d["H"][a:a + L].sum(0), d["g"][a:a + L].sum(0), d["c"][a:a + L].sum(), d["n_res"][a:a + L].sum())
        if f is not None:
            X.append(f[0])
            S.append(np.sqrt(np.clip(np.diag(f[1]), 1e-30, None)))
    return np.array(X).reshape(-1, 6), np.array(S).reshape(-1, 6)


def block_var_ratio(d: dict) -> dict:
    out = {}
    for L in BLOCKS:
        X, S = block_estimates(d, L)
        if len(X) < 4:
            continue
        Z = (X - X.mean(0)) / S
        out[L] = {"blocks": len(X), "ratio": dict(zip(AXES6, np.round((Z ** 2).sum(0) / (len(Z) - 1), 3).tolist()))}
    return out


def acf(d: dict, L: int = 5) -> dict:
    X, S = block_estimates(d, L)
    Z = (X - X.mean(0)) / S
    out = {}
    for i, a in enumerate(AXES6):
        z = Z[:, i]
        v = float(np.mean(z * z))
        out[a] = [round(float(np.mean(z[:-k] * z[k:]) / v), 3) if k < len(z) - 2 else None for k in LAGS]
    return out


def test_var_ratio(d: dict, history: int = 600, stride: int = 5) -> dict:
    """The monitor's recent-against-before tests recomputed from the frames' normal equations (no
    inflation): mean (d_i / sd_i)^2 per axis and mean chi2 / 6, per window length."""
    n = len(d["g"])
    C = np.concatenate([np.zeros((1, 6, 6)), np.cumsum(d["H"], 0)])
    G = np.concatenate([np.zeros((1, 6)), np.cumsum(d["g"], 0)])
    Cc = np.concatenate([[0.0], np.cumsum(d["c"])])
    N = np.concatenate([[0], np.cumsum(d["n_res"])])
    out = {}
    for L in TEST_LENGTHS:
        z2, chi = [], []
        for e in range(2 * L, n + 1, stride):
            s = max(0, e - history)
            fa = _fit(C[e] - C[e - L], G[e] - G[e - L], Cc[e] - Cc[e - L], N[e] - N[e - L])
            fb = _fit(C[e - L] - C[s], G[e - L] - G[s], Cc[e - L] - Cc[s], N[e - L] - N[s])
            if fa is None or fb is None:
                continue
            dx, cv = fa[0] - fb[0], fa[1] + fb[1]
            z2.append(dx * dx / np.diag(cv))
            chi.append(float(dx @ np.linalg.solve(cv, dx)) / 6)
        if z2:
            out[L] = {"tests": len(z2), "ratio": dict(zip(AXES6, np.round(np.mean(z2, 0), 3).tolist())),
                      "chi2_over_6_mean": round(float(np.mean(chi)), 3),
                      "chi2_over_6_p99": round(float(np.quantile(chi, 0.99)), 3)}
    return out


def per_object_share(d: dict, L: int = 80) -> dict | None:
    """Share of the L-frame block variance (per axis) that the objects' own offsets carry: in each
    block, every tracked object's (id >= 0) offset is estimated from its frames OUTSIDE the block
    (its pooled normal equations there, a random effect that persists along its track, shrunk by a
    prior of 0.1 deg / 5 cm per axis: one object's boxes rarely determine all six axes) and its
    expected share (H_k,o b_o) taken out of the block's frames. Offsets that persist make the
    block variance smaller; pure per-frame noise makes it larger (an independent estimate added)."""
    ids: dict[int, list] = {}
    for k, (o, oH, og) in enumerate(d["objects"]):
        if o is None:
            continue
        for j, i in enumerate(o):
            if i >= 0:
                ids.setdefault(int(i), []).append((k, oH[j], og[j]))
    if not ids:
        return None
    tot = {i: (sum(r[1] for r in rows), sum(r[2] for r in rows)) for i, rows in ids.items()}
    g2 = d["g"].copy()
    for a in range(0, len(g2) - L + 1, L):
        for i, rows in ids.items():
            inside = [r for r in rows if a <= r[0] < a + L]
            if not inside or len(inside) == len(rows):
                continue
            Ho = tot[i][0] - sum(r[1] for r in inside)
            go = tot[i][1] - sum(r[2] for r in inside)
            b = -np.linalg.solve(Ho + PRIOR_INFO, go)  # shrunk towards 0 where the object says little
            for k, Hk, _ in inside:
                g2[k] = g2[k] + Hk @ b
    before, after = block_var_ratio(d).get(L), block_var_ratio({**d, "g": g2}).get(L)
    if before is None or after is None:
        return None
    return {"objects": len(ids), "L": L, "ratio_before": before["ratio"], "ratio_objects_removed": after["ratio"]}


# ---------------------------------------------------------------- the change test replayed offline
# The default test's decisions recomputed from the recorded frames (``_Rec.row``: H, g, c, n_res,
# n_pairs), with the inflation's floor or a factor on the covariance changed: one recording gives
# every variant's false alarms and detections on the same frames. The leave-objects-out guard is not
# replayed (it only removes alarms), so a variant's false alarms here are an upper bound.

VARIANTS = {"default": {}, "min_inflation=0.75": {"floor": 0.75}, "min_inflation=0.5": {"floor": 0.5},
            "x0.8": {"factor": 0.8}, "x0.7": {"factor": 0.7}, "x0.6": {"factor": 0.6}}


def _cums(rows: np.ndarray) -> dict:
    C = np.concatenate([np.zeros((1, 46)), np.cumsum(rows, 0)])
    return {"H": C[:, :36].reshape(-1, 6, 6), "g": C[:, 36:42], "c": C[:, 42], "n": C[:, 43], "p": C[:, 44]}


def _seg_fit(C: dict, a: int, b: int):
    """``_Sums.fit`` over frames [a, b): x, covariance (residual variance factor at least 1), or None."""
    if C["p"][b] - C["p"][a] < 2 or C["n"][b] - C["n"][a] < 7:
        return None
    return _fit(C["H"][b] - C["H"][a], C["g"][b] - C["g"][a], C["c"][b] - C["c"][a], C["n"][b] - C["n"][a], 1e14)


def _adjacent_diffs(C: dict, e: int, W: int, minp: int, diffs: list, last, end: int):
    """The monitor's adjacent-window inflation step (``monitor.core._update_inflation``) at window end
    ``e``: when a new disjoint window of ``W`` frames is complete, its fit (None below ``minp``
    matches) and, if it follows the last one directly, their chi-square per degree of freedom appended
    to ``diffs`` (the last 200 kept). Returns (diffs, last fit, its end)."""
    if e - end >= W:
        f = _seg_fit(C, e - W, e) if C["p"][e] - C["p"][e - W] >= minp else None
        if f is not None and last is not None and end == e - W:
            d = f[0] - last[0]
            diffs = (diffs + [float(d @ np.linalg.solve(f[1] + last[1], d)) / 6])[-200:]
        last, end = f, e
    return diffs, last, end


def _inflation(diffs: list, floor: float) -> float:
    """The covariance inflation of ``diffs`` (``monitor.core``): the prior below ``MIN_DIFFS``, else the
    upper quartile over its chi-square value, at least ``floor``."""
    from xcalib.monitor.core import CHI2_6_Q75_OVER_6, INFLATION_PRIOR, MIN_DIFFS

    return INFLATION_PRIOR if len(diffs) < MIN_DIFFS else max(floor, float(np.quantile(diffs, 0.75)) / CHI2_6_Q75_OVER_6)


def decision_statistics(rows: np.ndarray, cov_cal: np.ndarray, floor: float = 1.0, factor: float = 1.0,
                        config=None) -> list[tuple[int, float, float]]:
    """(last frame index, the decision's largest statistic, inflation) at every decision of the
    default change test (``CameraMonitor._decide``: each recent window against the frames before it
    in the history, and the longest window's offset from the calibration), the adjacent-window
    inflation floored at ``floor`` and multiplied by ``factor``."""
    from xcalib.monitor import MonitorConfig

    cfg = config or MonitorConfig()
    W, stride, hist, minp = cfg.window, cfg.stride, cfg.history, cfg.min_pairs
    C = _cums(rows)
    out, diffs, last, end = [], [], None, -10 ** 9
    for e in range(W, len(rows) + 1, stride):
        diffs, last, end = _adjacent_diffs(C, e, W, minp, diffs, last, end)
        phi = _inflation(diffs, floor) * factor
        s = max(0, e - hist)
        lengths = [L for L in cfg.windows if L <= e - s] or [W]
        best = 0.0
        for L in lengths:
            if C["p"][e - L] - C["p"][s] < minp or C["p"][e] - C["p"][e - L] < minp:
                continue
            fa, fb = _seg_fit(C, e - L, e), _seg_fit(C, s, e - L)
            if fa is not None and fb is not None:
                d = fa[0] - fb[0]
                best = max(best, float(d @ np.linalg.solve((fa[1] + fb[1]) * phi, d)))
        fr = _seg_fit(C, e - lengths[-1], e)
        if fr is not None:
            best = max(best, float(fr[0] @ np.linalg.solve(fr[1] * phi + cov_cal, fr[0])))
        out.append((e - 1, best, phi))
    return out


def null_alarms(rows: np.ndarray, cov_cal: np.ndarray, h: float, **kw) -> tuple[int, float]:
    """Alarms of a variant on a drift-free recording (after one, ``window`` frames pass before the
    next decision can alarm, as after the monitor's restart), and its median inflation."""
    dec = decision_statistics(rows, cov_cal, **kw)
    alarms, quiet = 0, -1
    for fr, st, _ in dec:
        if fr >= quiet and st > h:
            alarms, quiet = alarms + 1, fr + 20
    return alarms, float(np.median([p for _, _, p in dec])) if dec else float("nan")


def first_detection(rows: np.ndarray, cov_cal: np.ndarray, h: float, **kw) -> int | None:
    """Frame index of a variant's first alarm on a recording, or None."""
    return next((fr for fr, st, _ in decision_statistics(rows, cov_cal, **kw) if st > h), None)


# ---------------------------------------------------------------- the change test with its guard
# ``replay`` recomputes the default monitor's decisions (``CameraMonitor._decide`` with
# ``latch=False``) from a recording (``load_recording``), the leave-objects-out guard included
# (``CameraMonitor._without_objects``, from the recorded per-object shares): every alarm the
# monitor would raise, the history forgotten after each (``reset``), as in the null benchmark.
# Not replayed: the residual scale (it shapes the recorded frames, which do not depend on the
# test) and the re-linearised test (off by default).


#: the variants ``--part guard`` replays: the inflation's floor (``MonitorConfig.min_inflation``)
#: and the objects the guard leaves out (``MonitorConfig.leave_out_objects``)
GUARD_VARIANTS = {"default": {}, "min_inflation=0.75": {"floor": 0.75}, "min_inflation=0.5": {"floor": 0.5},
                  "0.75,leave_out=3": {"floor": 0.75, "leave_out": 3}, "0.5,leave_out=3": {"floor": 0.5, "leave_out": 3},
                  "0.5,leave_out=4": {"floor": 0.5, "leave_out": 4}}


def _obj_sums(rec: dict, a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per object over frames [a, b): sorted ids, H [K,6,6], g [K,6] (``core._object_sums``)."""
    i0, i1 = np.searchsorted(rec["obj_frame"], [a, b])
    u, inv = np.unique(rec["obj_id"][i0:i1], return_inverse=True)
    H, g = np.zeros((len(u), 6, 6)), np.zeros((len(u), 6))
    np.add.at(H, inv, rec["obj_H"][i0:i1])
    np.add.at(g, inv, rec["obj_g"][i0:i1])
    return u, H, g


def _solve_rows(H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x = -H^-1 g, H^-1 and a usable flag per row (``core._solve_batch``)."""
    ev = np.linalg.eigvalsh(H)
    ok = (ev[:, 0] > 1e-10 * np.maximum(ev[:, -1], 1e-300)) & np.all(np.isfinite(ev), axis=1)
    inv = np.linalg.inv(np.where(ok[:, None, None], H, np.eye(6)[None]))
    return -np.einsum("kij,kj->ki", inv, g), inv, ok


def _chi2(d: np.ndarray, C: np.ndarray) -> float:
    try:
        return float(d @ np.linalg.solve(C, d))
    except np.linalg.LinAlgError:
        return float("inf") if np.any(d != 0) else 0.0


def _guarded(rec: dict, s: int, a: int, e: int, fa, fb, phi: float, cov_cal: np.ndarray, k_out: int,
             h_out: float, obj_a=None) -> float:
    """The statistic of the test of frames [a, e) against [s, a) (``fb`` None: against the
    calibration) with the ``k_out`` most influential objects of the recent frames left out of both,
    one at a time, stopping once it is at most ``h_out`` (``core.CameraMonitor._without_objects``)."""
    ids_a, Ha, ga = _obj_sums(rec, a, e) if obj_a is None else obj_a  # (obj_a: the iterated window's shares)
    Ta, ta = Ha.sum(0) if len(Ha) else np.zeros((6, 6)), ga.sum(0) if len(ga) else np.zeros(6)
    fac_a = float(np.trace(fa[1] @ Ta)) / 6.0
    if fb is not None:
        ids_b, Hb, gb = _obj_sums(rec, s, a)
        Tb, tb = Hb.sum(0) if len(Hb) else np.zeros((6, 6)), gb.sum(0) if len(gb) else np.zeros(6)
        fac_b = float(np.trace(fb[1] @ Tb)) / 6.0
        pos = np.clip(np.searchsorted(ids_b, ids_a), 0, max(len(ids_b) - 1, 0))
        inb = (ids_b[pos] == ids_a) if len(ids_b) else np.zeros(len(ids_a), bool)
        Hb_a = np.where(inb[:, None, None], Hb[pos] if len(ids_b) else 0.0, 0.0)
        gb_a = np.where(inb[:, None], gb[pos] if len(ids_b) else 0.0, 0.0)
        stat = _chi2(fa[0] - fb[0], (fa[1] + fb[1]) * phi)
    else:
        stat = _chi2(fa[0], fa[1] * phi + cov_cal)
    alive = np.ones(len(ids_a), dtype=bool)
    for _ in range(k_out):
        if not np.any(alive):
            break
        xa, ca, ok = _solve_rows(Ta[None] - Ha, ta[None] - ga)
        if fb is not None:
            xb, cb, okb = _solve_rows(Tb[None] - Hb_a, tb[None] - gb_a)
            d, C, ok = xa - xb, (ca * fac_a + cb * fac_b) * phi, ok & okb
        else:
            d, C = xa, ca * fac_a * phi + cov_cal[None]
        s_k = np.zeros(len(ids_a))
        if np.any(ok):
            s_k[ok] = np.einsum("ki,ki->k", d[ok], np.linalg.solve(C[ok], d[ok][..., None])[..., 0])
        s_k[~alive] = np.inf
        j = int(np.argmin(s_k))
        stat = float(s_k[j])
        alive[j] = False
        Ta, ta = Ta - Ha[j], ta - ga[j]
        if fb is not None:
            Tb, tb = Tb - Hb_a[j], tb - gb_a[j]
        if stat <= h_out:
            break
    return stat


def _few_objects(rec: dict, C: dict, a: int, b: int, cfg) -> bool:
    """``CameraMonitor._evidence``: too few matched pairs, or too few distinct tracked objects."""
    if C["p"][b] - C["p"][a] < cfg.min_pairs:
        return True
    i0, i1 = np.searchsorted(rec["obj_frame"], [a, b])
    ids = rec["obj_id"][i0:i1]
    ids = ids[ids >= 0]
    return 0 < len(ids) and len(np.unique(ids)) < cfg.min_objects


def edge_rows(rec: dict, a: int, b: int):
    """The unshaped residual rows of frames [a, b) of a recording (``iterate.stack_rows``' layout)."""
    i0, i1 = int(rec["edge_start"][a]), int(rec["edge_start"][b])
    cnt = np.diff(rec["edge_start"][a:b + 1])
    return (rec["edge_e0"][i0:i1], rec["edge_J"][i0:i1], rec["edge_sgn"][i0:i1], rec["edge_obj"][i0:i1],
            np.repeat(rec["edge_fs"][a:b], cnt))


def iterated_window(rec: dict, a: int, b: int, steps: int, cov_at: str = "iterate", part: str = ""):
    """(x, covariance, per-object shares) of frames [a, b) iterated ``steps`` Gauss-Newton steps on
    the unshaped rows (``xcalib.monitor.iterate.iterated_fit``), the covariance from the normal
    equations at the last linearisation (``cov_at="iterate"``) or at the calibration
    (``"calibration"``: the one-step test's), with the residual variance factor (at least 1)."""
    from xcalib.monitor.iterate import iterated_fit, object_shares

    cache = rec.setdefault("iterated_cache", {})  # the fits do not depend on the threshold: one per window
    key = (a, b, steps, cov_at, part)
    if key not in cache:
        cache[key] = _iterated_window(rec, a, b, steps, cov_at, part, iterated_fit, object_shares)
    return cache[key]


def _iterated_window(rec, a, b, steps, cov_at, part, iterated_fit, object_shares):
    rows = edge_rows(rec, a, b)
    if len(rows[0]) < 7:
        return None
    tau, slope = rec["occlusion"]
    got = iterated_fit(rows, steps, tau, slope, part=part)
    if got is None:
        return None
    xl, H, g, c = got
    f = _fit(H, g, c, len(rows[0]), 1e14)
    if f is None:
        return None
    x, cov = f
    if cov_at == "calibration":
        from xcalib.monitor.iterate import normal_equations

        f0 = _fit(*normal_equations(rows, np.zeros(6), tau, slope), len(rows[0]), 1e14)
        if f0 is None:
            return None
        cov = f0[1]
    return (x, cov), object_shares(rows, xl, tau, slope)


def _difference_scale(rec: dict, s: int, a: int, e: int, fa, fb, q: float, pools: dict) -> float:
    """``CameraMonitor._difference_scale`` on a recording: the test of [a, e) against [s, a) (the
    per-object sums from one ``SegmentTable`` per decision, split at the config's windows)."""
    from xcalib.monitor.core import DIFF_MIN_SAMPLES, DIFF_SAMPLES
    from xcalib.monitor.spread import SegmentTable, difference_ratio, tracked

    at, table = pools.get("table", (None, None))
    if at != (s, e, pools["windows"]):
        i0, i1 = np.searchsorted(rec["obj_frame"], [s, e])
        table = None
        if tracked(rec["obj_id"][i0:i1]):
            HG = np.concatenate([rec["obj_H"][i0:i1].reshape(-1, 36), rec["obj_g"][i0:i1]], 1)
            table = SegmentTable(rec["obj_frame"][i0:i1], rec["obj_id"][i0:i1], HG,
                                 [e - L for L in pools["windows"]])
        pools["table"] = ((s, e, pools["windows"]), table)
    if table is None:
        return 1.0
    after, before = table.split(a)
    r = difference_ratio(after, before, fa[0], fb[0], fa[1] + fb[1])
    pool = pools.setdefault(e - a, [])
    if np.isfinite(r):
        pool.append(r)
        del pool[:-DIFF_SAMPLES]
    if len(pool) < DIFF_MIN_SAMPLES or not np.isfinite(r):
        return 1.0
    return min(1.0, max(float(np.quantile(pool, q)), r))


def replay(rec: dict, floor: float = 1.0, factor: float = 1.0, leave_out: int | None = None,
           h_out: float | None = None, config=None, first_only: bool = False, threshold: float | None = None,
           iterate: int = -1, cov_at: str = "iterate", trace: list | None = None,
           windows: tuple[int, ...] | None = None) -> list[int]:
    """The frames (0-based) at which the monitor raises an alarm on the recording ``rec``
    (``load_recording``), with the adjacent-window inflation floored at ``floor`` and multiplied
    by ``factor``, ``leave_out`` objects left out by the guard (default: the config's) and the
    leave-out threshold ``h_out`` (default: the config's); after each alarm the history is
    forgotten (the benchmark's ``latch=False``); ``first_only``: stop at the first. ``iterate`` >= 0:
    the recent windows' estimates (and the offset test's) iterated that many Gauss-Newton steps on the
    recorded unshaped rows (``iterated_window``; -1, the default: the recorded one-step normal
    equations); ``trace``: a list to append (frame, largest statistic) of every decision to.
    ``windows``: the recent segments' lengths the change-point tests use (default the config's
    ``test_windows``: 20 / 40 / 80, or with ``MonitorConfig.change_point_step`` the change-point scan's);
    the offset test and the evidence check stay on the config's longest window."""
    from xcalib.monitor import MonitorConfig
    from xcalib.monitor import stats as mstats

    cfg = config or MonitorConfig()
    W, stride, hist, minp = cfg.window, cfg.stride, cfg.history, cfg.min_pairs
    h = float(cfg.threshold if threshold is None else threshold)
    k_out = int(cfg.leave_out_objects if leave_out is None else leave_out)
    if h_out is None:
        lvl = float(cfg.leave_out_level)
        h_out = mstats.threshold(lvl, 1, 1) if lvl > 0 else h
    rows, cov_cal = rec["rows"], rec["cov_cal"]
    C = _cums(rows)
    alarms: list[int] = []
    diffs: list[float] = []
    pools: dict = {}  # per window length: the objects' spread ratios (``difference_quantile``; kept after alarms)
    start, last, end = 0, None, -10 ** 9
    e = W
    while e <= len(rows):
        s = max(start, e - hist)
        diffs, last, end = _adjacent_diffs(C, e, W, minp, diffs, last, end)  # (``_update_inflation``)
        phi = _inflation(diffs, floor) * factor
        longest = max([L for L in cfg.windows if L <= e - s] or [W])
        tested = cfg.test_windows if windows is None else windows  # the change-point tests' recent segments
        lengths = [L for L in tested if L <= e - s] or [min(tested)]
        pools["windows"] = tuple(lengths)
        fr = None if _few_objects(rec, C, e - longest, e, cfg) else _seg_fit(C, e - longest, e)
        alarm = False
        if fr is not None:
            tests = []
            its = {}
            if iterate >= 0:
                for L in set(lengths) | {longest}:
                    its[L] = iterated_window(rec, e - L, e, iterate, cov_at)
                fr_i = its.get(longest)
            for L in lengths:
                if C["p"][e - L] - C["p"][s] < minp or C["p"][e] - C["p"][e - L] < minp:
                    continue
                fa, fb = _seg_fit(C, e - L, e), _seg_fit(C, s, e - L)
                oa = None
                if iterate >= 0:
                    fa, oa = its[L] if its[L] is not None else (None, None)
                if fa is not None and fb is not None:
                    if cfg.difference_quantile > 0 and oa is None:  # (``CameraMonitor._difference_scale``)
                        k_d = _difference_scale(rec, s, e - L, e, fa, fb, cfg.difference_quantile, pools)
                        fa, fb = (fa[0], fa[1] * k_d), (fb[0], fb[1] * k_d)
                    tests.append((_chi2(fa[0] - fb[0], (fa[1] + fb[1]) * phi), e - L, fa, fb, oa))
            if iterate >= 0 and fr_i is not None:
                tests.append((_chi2(fr_i[0][0], fr_i[0][1] * phi + cov_cal), e - longest, fr_i[0], None, fr_i[1]))
            elif iterate < 0:
                tests.append((_chi2(fr[0], fr[1] * phi + cov_cal), e - longest, fr, None, None))
            if trace is not None:
                trace.append((e - 1, max([q[0] for q in tests] or [0.0])))
            for st, a, fa, fb, oa in sorted(tests, key=lambda q: -q[0]):
                if st <= h:
                    break
                if _guarded(rec, s, a, e, fa, fb, phi, cov_cal, k_out, h_out, oa) > h_out:
                    alarm = True
                    break
        if alarm:
            alarms.append(e - 1)
            if first_only:
                break
            start, last, end = e, None, -10 ** 9  # ``CameraMonitor.reset`` (the inflation's pairs are kept)
            e = start + W
            continue
        e += stride
    return alarms


def step_recovery(rec: dict, k0: int, length: int, axis: int, true: float) -> dict:
    """How much of a step of size ``true`` on ``axis`` (rad / m) injected at frame ``k0`` the
    monitor's linearised frames recover: the ``length`` frames after it fitted against the ``k0``
    before (``_seg_fit``, linearised at the calibration as the change test is): the estimate over
    the truth, its z, the two-sample statistic, and the noncentrality the true step would have at
    the same covariance (what an unshrunk estimate would give on average)."""
    C = _cums(rec["rows"])
    fb, fa = _seg_fit(C, 0, k0), _seg_fit(C, k0, k0 + length)
    d, cov = fa[0] - fb[0], fa[1] + fb[1]
    t = np.zeros(6)
    t[axis] = true
    return {"recovered": float(d[axis] / true), "z": float(d[axis] / np.sqrt(cov[axis, axis])),
            "statistic": float(d @ np.linalg.solve(cov, d)), "noncentrality_true": float(t @ np.linalg.solve(cov, t))}


def save_recording(path, d: dict) -> None:
    """One recording (``collect``) as a plain ``.npz`` (no pickle): the frames' rows, the
    per-object shares flattened (frame, id, H, g per matched object), cov_cal and the threshold."""
    fr, ids, oH, og = [], [], [], []
    for k, (o, H, g) in enumerate(d["objects"]):
        if o is None or not len(o):
            continue
        fr.append(np.full(len(o), k))
        ids.append(np.asarray(o, dtype=np.int64))
        oH.append(np.asarray(H).reshape(-1, 36))
        og.append(np.asarray(g).reshape(-1, 6))
    cat = lambda v, shape: np.concatenate(v) if v else np.zeros(shape)  # noqa: E731
    extra = {}
    if d.get("edges") is not None:  # the unshaped residual rows (``xcalib.monitor.iterate``)
        ed = d["edges"]
        extra = {"edge_count": np.array([0 if q is None else len(q.e0) for q in ed], dtype=np.int64),
                 "edge_e0": cat([q.e0 for q in ed if q is not None], (0,)),
                 "edge_J": cat([q.J for q in ed if q is not None], (0, 6)),
                 "edge_sgn": cat([q.sgn for q in ed if q is not None], (0,)).astype(np.int8),
                 "edge_obj": cat([q.obj for q in ed if q is not None], (0,)).astype(np.int64),
                 "edge_fs": np.array([np.nan if q is None else q.fs for q in ed]),
                 "occlusion": np.asarray(d["occlusion"], dtype=np.float64)}
    np.savez_compressed(path, rows=d["rows"], cov_cal=d["cov_cal"], threshold=d["threshold"],
                        obj_frame=cat(fr, (0,)).astype(np.int64), obj_id=cat(ids, (0,)).astype(np.int64),
                        obj_H=cat(oH, (0, 36)), obj_g=cat(og, (0, 6)), **extra)


def load_recording(path) -> dict:
    """``save_recording``'s file back: rows, cov_cal, threshold and the per-object shares."""
    z = np.load(path, allow_pickle=False)
    out = {"rows": z["rows"], "cov_cal": z["cov_cal"], "threshold": float(z["threshold"]),
           "obj_frame": z["obj_frame"], "obj_id": z["obj_id"], "obj_H": z["obj_H"].reshape(-1, 6, 6),
           "obj_g": z["obj_g"]}
    if "edge_count" in z.files:  # recorded with the unshaped residual rows
        out.update({"edge_start": np.concatenate([[0], np.cumsum(z["edge_count"])]), "edge_e0": z["edge_e0"],
                    "edge_J": z["edge_J"].reshape(-1, 6), "edge_sgn": z["edge_sgn"].astype(np.float64),
                    "edge_obj": z["edge_obj"], "edge_fs": z["edge_fs"], "occlusion": tuple(z["occlusion"])})
    return out


def analyse(d: dict) -> dict:
    """The persistence figures of one recording (``collect``)."""
    return {"frames": len(d["g"]), "alarms": d["alarms"], "cpu_ms_per_frame": round(d["cpu_ms"], 2),
            "inflation_median": round(float(np.median(d["inflation"])), 3) if d["inflation"] else None,
            "block_var_ratio": block_var_ratio(d), "acf_5frame_blocks": acf(d),
            "test_var_ratio": test_var_ratio(d), "per_object_share": per_object_share(d)}


def _print(name: str, r: dict, log) -> None:
    log(f"== {name}: {r['frames']} frames, {r['alarms']} alarms, inflation median {r['inflation_median']}, "
        f"{r['cpu_ms_per_frame']} ms/frame")
    for L, v in r["block_var_ratio"].items():
        log(f"  block L={L:3d} ({v['blocks']:4d}) var ratio " + " ".join(f"{a} {x:5.2f}" for a, x in v["ratio"].items()))
    for a in ("rx", "tz", "tx"):
        log(f"  acf {a} lags 5..80 fr: " + " ".join("-" if x is None else f"{x:+.2f}" for x in r["acf_5frame_blocks"][a]))
    for L, v in r["test_var_ratio"].items():
        log(f"  test L={L:3d} ({v['tests']:4d}) mean z^2 " + " ".join(f"{a} {x:5.2f}" for a, x in v["ratio"].items())
            + f"  chi2/6 mean {v['chi2_over_6_mean']:.2f} p99 {v['chi2_over_6_p99']:.2f}")
    p = r["per_object_share"]
    if p:
        log(f"  objects' own offsets removed (L={p['L']}, {p['objects']} objects): " + " ".join(
            f"{a} {p['ratio_before'][a]:.2f}->{p['ratio_objects_removed'][a]:.2f}" for a in AXES6))


def synthetic(seeds, n, log) -> dict:
    import bench_monitor as bm

    out = {}
    for name, noise in (("default", {}), ("noisy", {"box_noise_px": 4.0, "miss_rate_2d": 0.1})):
        for s in seeds:
            site, frames = bm._synth_stream(s, n, **noise)
            r = analyse(collect(bm._synth_calibration(site), frames))
            _print(f"synthetic site {s} {name}", r, log)
            out[f"site_{s}_{name}"] = r
    return out


def real(n: int, log) -> dict:
    """The looped real sets of ``bench_monitor.py`` (A9 with its own calibration, PandaSet 002 and
    KITTI rebased to one pose), ``n`` frames each; a set whose data is absent is left out."""
    import bench_monitor as bm

    out = {}
    if bm.A9.exists():
        from xcalib.calib.api import calibrate
        from xcalib.io.sources import open_source

        seq = open_source(bm.A9)
        raw = [seq[i] for i in range(len(seq))]
        cal = calibrate(raw, None)
        if cal.success:
            out["a9"] = analyse(collect(cal, bm._replay(raw, n, 1, 1.0)))
            _print("A9 (16 frames looped)", out["a9"], log)
    for name, root, make, jit in (("pandaset", bm.SHARED / "pandaset_002", bm._pandaset_base, 0.5),
                                  ("kitti", bm.SHARED / "kitti" / "openpcdet_pr653" / "training", bm._kitti_base, 1.0)):
        if not root.exists():
            continue
        base, cal = make(root)
        out[name] = analyse(collect(cal, bm._replay(base, n, 1, jit)))
        _print(f"{name} (looped)", out[name], log)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--sites", default="3,5,11,17")
    ap.add_argument("--frames", type=int, default=800, help="frames per synthetic stream")
    ap.add_argument("--real-frames", type=int, default=800, help="frames per looped real stream (0: none)")
    ap.add_argument("--out", default=None, help="write the figures to this JSON (default: print only)")
    args = ap.parse_args(argv)
    log = lambda *a, **k: print(*a, **{"flush": True, **k})  # noqa: E731
    res = {"synthetic": synthetic([int(s) for s in args.sites.split(",") if s], args.frames, log)}
    if args.real_frames:
        res["real"] = real(args.real_frames, log)
    if args.out:
        Path(args.out).write_text(json.dumps(res, indent=1, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
