"""Drift monitor benchmark (issue 27): detection delay, detection rate, false alarms per 10,000
frames, estimated-change error and CPU per frame, on synthetic streams and on A9 with injected drift.

Synthetic (``xcalib.data.synth``, 10 Hz, roadside sites with 15-30 objects per sequence, the
detector's yawed 3D boxes, calibration = the true pose with 1-sigma 0.05 deg / 2 cm):

* null streams: default detection noise, and 4 px box noise + 10 % missed 2D detections
  (``--null-frames`` per site; ``--full``: 18,000 = 30 min); sparse traffic (2-5 objects);
* steps of 0.25 / 0.5 deg about camera x, y, z and 10 / 20 cm along x, y, z, injected
  (``xcalib.monitor.inject``: the 3D boxes moved by ``T'^-1 T``) at a frame 250 frames into the
  monitored stream; runs over sites and change points; detected within 50 (0.25 deg / 10 cm) or
  20 (0.5 deg / 20 cm) frames, delay, rate within 100 frames, the estimated step's error at
  detection and 50 / 100 frames after the change (|estimate - truth| / |truth| of the changed kind);
* ramps: 0.5 deg about x and 20 cm along x over 300 frames (30 s).

A9 (``../shared/data/a9_sample``, 16 real frames looped with 1 px jitter and 10 % dropped 2D boxes
per pass; calibration = ``calibrate`` on the 16 frames; the yaw-less boxes keep their clouds, so
the monitor fits their yaw every frame): a drift-free stream and the injected steps at the
middle of ``--real-frames``; CPU per frame (``time.process_time`` of ``update``, one thread)
against ``calibrate`` on one 20-frame window of the same frames in the same run. Estimate errors
at detection and 50 / 100 frames after the change, per kind (rotation in deg, translation in m,
never mixed; the other kind's leak separately).

Long drift-free streams (``--part null``): ``--null-base`` generated frames per site looped with
fresh 0.5 px jitter and 5 % extra misses per pass (the generator costs ~11 ms a frame, the monitor
~3 ms). Real sequences (``--part real``): PandaSet 002 (2D boxes projected from the real cuboids)
and KITTI (6 labelled frames), rebased to one camera and pose, looped with jitter, injected steps
at the middle of ``--real-frames``. ``--part weak``: the z steps and an x control with the
weak-axes statement the last ok decision before the change made.

Prints tables and writes ``benchmarks/results/monitor.json`` (each part merges its keys).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_monitor.py --part synth --sites 2 --runs 8 --null-frames 800
    ... --part null --null-noise noisy --null-frames 5000 --null-base 1200 --null-sites 6
    ... --part null --null-noise default --null-frames 5000 --null-base 1200 --null-sites 4
    ... --part a9 --real-null 1600 --real-frames 320
    ... --part real --real-null 1600 --real-frames 320
    ... --part weak --sites 2 --runs 8 --null-frames 800
    ... --part reference --sites 2 --runs 8 --null-frames 800 --reference-frames 2400
    ... --part bound --null-seeds 3,5,7,11,13,17 --info-frames 500 --bound-runs --runs 8

``--part bound``: per site (``--null-seeds``) and for A9, the Cramer-Rao bound of the z steps
and the power of efficient tests at the false-alarm rate with the change time known
(``monitor_information.efficient_rows``) and unknown (``sequential_rows``), beside the site's
geometry (``site_geometry``) and, with ``--bound-runs``, the monitor's own z steps there.

``--part relin``: the re-linearised window test (``MonitorConfig.relinearise_band``) recorded
without alarming on the long null streams and the z step cells (``--step-seeds``), read off per
factor on the threshold (``_relin``); ``--part relin_a9``: its CPU at A9 density; ``--part
verdict``: each z step cell against the bound at its site (detected / possible / impossible;
reads ``monitor.json``, runs nothing).

    ... --part relin --null-frames 3400 --null-base 1200 --null-seeds 3,5,7,11,13,17 --step-seeds 3,5,11,17 --runs 8
    ... --part relin_a9 --real-null 800 --real-frames 320 --relin-band 0.4 --relin-factor 2
    ... --part verdict

``--part persist``: do the frames' errors persist over frames (``monitor_persistence``: block
variance against the stated one per window length and axis, autocorrelation, the tests' null
spread) on the null streams, the z step cells (``PERSIST_CELLS``, ``--runs`` per ``--step-seeds``
site) and the looped real sets (``--real-null`` frames); the change test's variants
(``monitor_persistence.VARIANTS``: the inflation's floor lowered, a factor on the covariance)
replayed offline on the same recorded frames (``monitor.json`` ``persist_s10``).

    ... --part persist --null-frames 2400 --null-base 1200 --null-seeds 3,5,11,17 --step-seeds 3,11,17 --runs 2 --real-null 480 --jobs 2

``--part guard``: the inflation's floor (``MonitorConfig.min_inflation``) with the leave-objects-out
guard's size (``leave_out_objects``), ``monitor_persistence.GUARD_VARIANTS``, replayed with the guard
(``monitor_persistence.replay``) on recordings of the long null streams and of every step cell
(``--recordings``: the .npz folder, reused when present) (``monitor.json`` ``guard_s11``).

    ... --part guard --null-frames 3400 --null-base 1200 --null-seeds 3,5,7,11,13,17 --step-seeds 3,5,7,11,13,17 --runs 2

``--part scan``: the change-point scan (``MonitorConfig.change_point_step``) against the fixed windows, replayed
on the recordings of ``--part iterate`` (``--recordings``; made when absent) (``monitor.json`` ``scan_s13``).

    ... --part scan --null-frames 3400 --null-base 1200 --null-seeds 3,5,7,11,13,17 --step-seeds 3,5,7,11,13,17 --runs 2

``--part pairnoise``: the noise model's 3D-box part weighted per pair (``MonitorConfig.pair_noise``) against the
independent per-edge model, both recorded (``--recordings`` / ``--pair-recordings``; made when absent) and replayed
with the default change test (``monitor.json`` ``pairnoise_<--label>``, ``pairnoise_s14M3``).

    ... --part pairnoise --null-frames 3400 --null-base 1200 --null-seeds 3,5,7,11,13,17 --step-seeds 3,5,7,11,13,17 --runs 2 --recordings DIR --pair-recordings DIR2

``--part spread``: the change test's covariance at the objects' own spread of the two segments' difference
(``MonitorConfig.difference_quantile``, each of ``--quantiles``) against the default, replayed on the recordings of
``--part iterate`` (``--recordings``; made when absent) (``monitor.json`` ``spread_<--label>``).

    ... --part spread --null-frames 3400 --null-base 1200 --null-seeds 3,5,7,11,13,17 --step-seeds 3,5,7,11,13,17 --runs 2 --recordings DIR --label s15M4

``--part reference``: the change test calibrated per axis and window length
(``CameraMonitor.axis_factors``) from a drift-free reference stretch of each site
(``Monitor.learn``), against the test without it and with only the stream's own ~250 frames, on
the same step segments (z steps: the axis the covariance overstated most).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_calibration import machine_info, write_result  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("XCALIB_SHARED_DATA", REPO.parent / "shared" / "data"))
A9 = SHARED / "a9_sample"
AXES = "xyz"
STEPS = [("rotation", 0.25, 50), ("rotation", 0.5, 20), ("translation", 0.10, 50), ("translation", 0.20, 20)]
PRE, POST = 250, 100


def _change(kind: str, size: float, axis: int) -> tuple[np.ndarray, np.ndarray]:
    r, t = np.zeros(3), np.zeros(3)
    (r if kind == "rotation" else t)[axis] = size
    return r, t


def _synth_stream(seed: int, n: int, **kw):
    from xcalib.data.synth import iter_frames, sample_site

    site = sample_site(seed, n_objects=kw.pop("n_objects", (15, 30)))
    frames = [replace(f, bboxes_3d=np.asarray(f.meta["box7"], dtype=np.float32))
              for f in iter_frames(site, n, 0, render_images=False, lidar=False, **kw)]
    return site, frames


def _synth_calibration(site):
    from xcalib.calib.result import CalibrationResult

    T = site.T_cam_lidar
    return CalibrationResult(success=True, intrinsics=site.intrinsics_given, rotation=T[:3, :3], translation=T[:3, 3],
                             rotation_std_deg=np.full(3, 0.05), translation_std_m=np.full(3, 0.02),
                             camera_name=site.camera_name, image_size=(site.width, site.height))


def _run(cal, frames, *, k0: int | None = None, change=None, ramp: int = 0, latch: bool = True,
         settle: tuple[int, ...] = (50, 100), monitor=None) -> dict:
    """Monitor ``frames`` (any iterable; a change from frame ``k0``: a step, or over ``ramp``
    frames a ramp). Returns the first detection, the step estimate at detection and ``settle``
    frames after the change (the latched estimate: the frames since the change point refitted),
    states, alarms, CPU (``time.process_time`` of ``update`` only). ``monitor``: a fresh
    ``Monitor`` to use (one that learned a reference stretch) instead of a new one."""
    from xcalib.monitor import Monitor, MonitorConfig
    from xcalib.monitor.inject import inject_change

    mon = monitor if monitor is not None else Monitor(cal, MonitorConfig(**{"latch": latch, **CONFIG}))
    cm = next(iter(mon.cameras.values()))
    states = {"ok": 0, "drift": 0, "unknown": 0}
    weak: dict[str, int] = {}
    first, est_first, alarms, cpu, n = None, None, 0, 0.0, 0
    settled, weak_before, settled_alt = {}, None, {}
    for i, f in enumerate(frames):
        if change is not None and i >= k0:
            frac = 1.0 if not ramp else min(1.0, (i - k0 + 1) / ramp)
            f = inject_change(f, cal, change[0] * frac, change[1] * frac)
        t0 = time.process_time()
        sts = mon.update(f)
        cpu += time.process_time() - t0
        n += 1
        for st in sts:
            states[st.state] += 1
            for a in st.weak_axes:
                weak[a] = weak.get(a, 0) + 1
            if k0 is not None and i < k0 and st.state == "ok":
                weak_before = st.weak_axes
        if len(cm.events) > alarms:
            alarms = len(cm.events)
            if first is None:
                first = i
                est_first = cm.events[-1].step.copy()
        if k0 is not None and latch and cm.events and i - k0 + 1 in settle:
            settled[i - k0 + 1] = cm.events[0].step.copy()
            alt = cm.events[0].alternative
            settled_alt[i - k0 + 1] = None if alt is None else alt.copy()
    return {"first": first, "est_first": est_first, "settled": settled, "settled_alt": settled_alt,
            "states": states, "alarms": alarms,
            "cpu_ms": 1e3 * cpu / max(n, 1), "frames": n, "weak": weak,
            "weak_before": weak_before,
            "model": cm.events[0].model if cm.events else None,
            "alarm_frames": [int(e.detected_frame) for e in cm.events],
            "relin": [tuple(v) for v in cm.relin_trace], "threshold": float(cm.h)}


def _rel_err(est, kind: str, size: float, axis: int) -> float | None:
    """|estimate - truth| / |truth| of the changed kind (rotation deg or translation m; the other
    kind's leak is ``_leak``): units are never mixed."""
    if est is None:
        return None
    sl = slice(0, 3) if kind == "rotation" else slice(3, 6)
    true = np.zeros(3)
    true[axis] = size
    return float(np.linalg.norm(est[sl] - true) / size)


def _either(q: dict, at: int, kind: str, size: float, axis: int) -> float | None:
    """The error of the better of the step and its ambiguous alternative (where reported)."""
    errs = [_rel_err(e, kind, size, axis) for e in (q["settled"].get(at), q.get("settled_alt", {}).get(at))]
    errs = [e for e in errs if e is not None]
    return min(errs) if errs else None


def _leak(est, kind: str) -> float | None:
    """The size of the other kind in the estimate (deg for a translation step, m for a rotation step)."""
    if est is None:
        return None
    return float(np.linalg.norm(est[3:] if kind == "rotation" else est[:3]))


def _share(v) -> float | None:
    """Share of runs whose error is <= 25 % (a run with no estimate counts as a miss)."""
    return float(np.mean([x is not None and x <= 0.25 for x in v])) if v else None


def _pct(v) -> float | None:
    v = [x for x in v if x is not None]
    return float(np.median(v)) if v else None


_STREAMS: dict = {}  # the synthetic streams the step runs share (worker processes inherit them by fork)
JOBS = 1  # worker processes (``--jobs``)
CONFIG: dict = {}  # MonitorConfig settings other than the defaults (``--set``)


def _pmap(fn, items: list):
    """``[fn(x) for x in items]``, in ``JOBS`` forked worker processes when JOBS > 1 (order kept)."""
    if JOBS <= 1 or len(items) <= 1:
        return map(fn, items)  # lazy: each result is logged as it is done
    import multiprocessing as mp

    with mp.get_context("fork").Pool(min(JOBS, len(items))) as pool:
        return pool.map(fn, items)


def _step_runs(cell) -> list[dict]:
    kind, size, within, axis, runs = cell
    keys = list(_STREAMS)
    res = []
    for r in range(runs):
        seed = keys[r % len(keys)]
        site, frames = _STREAMS[seed]
        k0 = PRE + ((r // len(keys)) * 137) % max(len(frames) - PRE - POST, 1)
        seg = frames[k0 - PRE:k0 + POST]
        res.append(_run(_synth_calibration(site), seg, k0=PRE, change=_change(kind, size, axis)))
    return res


def _steps(streams: dict, runs: int, log, cells=None) -> list[dict]:
    """``cells``: (kind, size, within, axis) to run (default: every STEPS size on every axis)."""
    _STREAMS.clear()
    _STREAMS.update(streams)
    cells = cells or [(k, s, w, a) for k, s, w in STEPS for a in range(3)]
    results = _pmap(_step_runs, [(*c, runs) for c in cells])
    return [_summarise(f"step {size:g} {'deg' if kind == 'rotation' else 'm'} {kind} {AXES[axis]}",
                       res, kind, size, axis, within, PRE, log) for (kind, size, within, axis), res in zip(cells, results)]


def _summarise(name, res, kind, size, axis, within, k0, log) -> dict:
    delays = [None if q["first"] is None or q["first"] < k0 else q["first"] - k0 for q in res]
    early = sum(1 for q in res if q["first"] is not None and q["first"] < k0)
    ok = [d for d in delays if d is not None]
    unit = "deg" if kind == "rotation" else "m"
    row = {"case": name, "runs": len(res), "within": within,
           "detected_within": float(np.mean([d is not None and d <= within for d in delays])),
           "detected_100": float(np.mean([d is not None and d <= 100 for d in delays])),
           "delay_median": float(np.median(ok)) if ok else None, "delay_max": int(max(ok)) if ok else None,
           "alarm_before_change": early,
           "est_err_at_detection": _pct([_rel_err(q["est_first"], kind, size, axis) for q in res]),
           "est_err_at_change_plus_50": _pct([_rel_err(q["settled"].get(50), kind, size, axis) for q in res]),
           "est_err_at_change_plus_100": _pct([_rel_err(q["settled"].get(100), kind, size, axis) for q in res]),
           "est_within_25pct_at_plus_50": _share([_rel_err(q["settled"].get(50), kind, size, axis) for q in res]),
           "leak_other_kind_at_plus_50": _pct([_leak(q["settled"].get(50), kind) for q in res]),
           # the step was reported ambiguous (a pure rotation and a pure translation both fit) ...
           "ambiguous_at_plus_50": float(np.mean([q.get("settled_alt", {}).get(50) is not None for q in res])),
           # ... and the better of the two readings
           "est_err_either_at_plus_50": _pct([_either(q, 50, kind, size, axis) for q in res]),
           "axis_right": float(np.mean([q["settled"].get(100) is not None and
                                        int(np.argmax(np.abs(q["settled"][100]))) == (0 if kind == "rotation" else 3) + axis
                                        for q in res])),
           # the last ok decision before the change named this axis not observable at the target size
           "weak_axis_stated": float(np.mean([(("r" if kind == "rotation" else "t") + AXES[axis]) in
                                              (q["weak_before"] or ()) for q in res])),
           "cpu_ms_per_frame": float(np.mean([q["cpu_ms"] for q in res])), "size": size, "unit": unit}
    log(f"{name:34s} {row['detected_within'] * 100:5.0f} % <= {within:2d} fr  {row['detected_100'] * 100:4.0f} % <= 100  "
        f"delay {_f(row['delay_median'])} (max {_f(row['delay_max'])})  err@det {_f(row['est_err_at_detection'], 2)} "
        f"err@+50 {_f(row['est_err_at_change_plus_50'], 2)} (<=25 %: {_f(row['est_within_25pct_at_plus_50'], 2)}) "
        f"err@+100 {_f(row['est_err_at_change_plus_100'], 2)}  ambiguous {row['ambiguous_at_plus_50'] * 100:.0f} % "
        f"(either {_f(row['est_err_either_at_plus_50'], 2)})  axis {row['axis_right'] * 100:.0f} %  early {early}  "
        f"stated weak {row['weak_axis_stated'] * 100:.0f} %")
    return row


REF_CELLS = [("translation", 0.10, 50, 2), ("translation", 0.20, 20, 2), ("translation", 0.10, 50, 0)]


def _ref_runs(cell) -> list[dict]:
    """One cell's runs in one arm: ``off`` (reference_samples=0, the default: the single
    adjacent-window inflation), ``online`` (reference_samples=REFERENCE_SAMPLES: the per-axis
    factors from the stream's own decisions, ~250 frames before the change), ``reference`` (a copy of the monitor
    that learned the site's reference stretch first)."""
    import copy

    from xcalib.monitor import Monitor, MonitorConfig
    from xcalib.monitor.core import REFERENCE_SAMPLES

    arm, kind, size, within, axis, runs = cell
    keys = list(_STREAMS)
    res = []
    for r in range(runs):
        seed = keys[r % len(keys)]
        site, frames, learned = _STREAMS[seed]
        cal = _synth_calibration(site)
        k0 = PRE + ((r // len(keys)) * 137) % max(len(frames) - PRE - POST, 1)
        seg = frames[k0 - PRE:k0 + POST]
        mon = (copy.deepcopy(learned) if arm == "reference" else
               Monitor(cal, MonitorConfig(**{**CONFIG, "reference_samples": 0 if arm == "off" else REFERENCE_SAMPLES})))
        res.append(_run(cal, seg, k0=PRE, change=_change(kind, size, axis), monitor=mon))
    return res


def _reference(seeds: list[int], n_ref: int, n_stream: int, runs: int, log,
               arms: tuple[str, ...] = ("off", "online", "reference")) -> dict:
    """The per-axis calibration of the change test (``CameraMonitor.axis_factors``), measured: per
    site one stream of ``n_ref`` + ``n_stream`` generated frames; the first ``n_ref`` are the
    site's drift-free reference stretch (``Monitor.learn``), the steps are injected 250 frames
    into segments of the rest, in three arms (``_ref_runs``) on the same segments."""
    from xcalib.monitor import Monitor, MonitorConfig
    from xcalib.monitor.core import REFERENCE_SAMPLES

    _STREAMS.clear()
    out = {"reference_frames": n_ref, "runs_per_cell": runs, "sites": seeds, "factors": {}}
    for s in seeds:
        site, frames = _synth_stream(s, n_ref + n_stream)
        mon = Monitor(_synth_calibration(site), MonitorConfig(**{**CONFIG, "reference_samples": REFERENCE_SAMPLES}))
        summ = mon.learn(frames[:n_ref])
        out["factors"][f"site_{s}"] = summ
        log(f"site {s}: reference {n_ref} frames: " + "; ".join(
            f"{k} ({v['samples']} samples) " + (", ".join(f"{a} {x:.2f}" for a, x in v["variance_factors"].items())
                                                if v["variance_factors"] else "-")
            for k, v in next(iter(summ.values())).items() if k.startswith("window")), flush=True)
        _STREAMS[s] = (site, frames[n_ref:], mon)
    for arm in arms:
        log(f"-- arm {arm}")
        rows = [_summarise(f"{arm}: step {size:g} {'deg' if kind == 'rotation' else 'm'} {kind} {AXES[axis]}",
                           res, kind, size, axis, within, PRE, log)
                for (kind, size, within, axis), res in zip(REF_CELLS, _pmap(_ref_runs, [(arm, *c, runs) for c in REF_CELLS]))]
        out[arm] = rows
    return out


def _f(v, d: int = 0) -> str:
    return "-" if v is None else f"{v:.{d}f}"


def _ramps(streams: dict, runs: int, log) -> list[dict]:
    rows = []
    keys = list(streams)
    for kind, size in (("rotation", 0.5), ("translation", 0.2)):
        res = []
        for r in range(runs):
            site, frames = streams[keys[r % len(keys)]]
            seg = frames[:PRE + 300]
            res.append(_run(_synth_calibration(site), seg, k0=PRE, change=_change(kind, size, 0), ramp=300))
        delays = [None if q["first"] is None or q["first"] < PRE else q["first"] - PRE for q in res]
        at_det = [None if d is None else size * min(1.0, (d + 1) / 300) for d in delays]
        errs = [None if q["est_first"] is None or a is None else
                abs(q["est_first"][(0 if kind == "rotation" else 3)] - a) / a for q, a in zip(res, at_det)]
        ok = [d for d in delays if d is not None]
        row = {"case": f"ramp {size:g} {'deg' if kind == 'rotation' else 'm'} {kind} x over 300 frames",
               "runs": len(res), "detected": float(np.mean([d is not None for d in delays])),
               "delay_median": float(np.median(ok)) if ok else None,
               "true_change_at_detection_median": _pct(at_det), "est_err_at_detection": _pct(errs)}
        log(f"{row['case']:48s} detected {row['detected'] * 100:.0f} %  delay {_f(row['delay_median'])} frames  "
            f"true change at detection {_f(row['true_change_at_detection_median'], 3)}  err {_f(row['est_err_at_detection'], 2)}")
        rows.append(row)
    return rows


def _tally(runs: list[dict]) -> tuple[int, int, int, int, list[float]]:
    """Totals over monitor runs (``_run``): frames, alarms, 'unknown' states, decisions, cpu ms each."""
    return (sum(q["frames"] for q in runs), sum(q["alarms"] for q in runs),
            sum(q["states"]["unknown"] for q in runs), sum(sum(q["states"].values()) for q in runs),
            [q["cpu_ms"] for q in runs])


def _null(name: str, streams: dict, log) -> dict:
    frames_total, alarms, unknown, decisions, cpu = _tally(
        [_run(_synth_calibration(site), frames, latch=False) for site, frames in streams.values()])
    upper = 3.0 / frames_total * 1e4 if alarms == 0 else None  # 95 % upper bound for zero events
    row = {"case": name, "frames": frames_total, "false_alarms": alarms,
           "false_alarms_per_10k": alarms / frames_total * 1e4, "upper95_per_10k_if_zero": upper,
           "unknown_share": unknown / max(decisions, 1), "cpu_ms_per_frame": float(np.mean(cpu))}
    log(f"{name:40s} {frames_total:6d} frames  {alarms} false alarms ({row['false_alarms_per_10k']:.2f} per 10k"
        f"{'' if upper is None else f'; 95 % bound {upper:.1f}'})  unknown {100 * row['unknown_share']:.0f} %  "
        f"cpu {row['cpu_ms_per_frame']:.2f} ms/frame")
    return row


def _replay(base: list, n: int, seed: int, jitter_px: float = 1.0, drop: float = 0.1):
    """A stream of ``n`` frames looping over ``base`` (lazy): every pass draws fresh 2D box
    jitter (``jitter_px`` std per coordinate) and drops ``drop`` of the 2D boxes at random, so
    no two passes hand the monitor the same boxes; 10 Hz times."""
    rng = np.random.default_rng([seed, 27])
    for i in range(n):
        f = base[i % len(base)]
        b2 = np.asarray(f.bboxes_2d, dtype=np.float64).reshape(-1, 4)
        keep = rng.random(len(b2)) >= drop
        b2 = b2[keep] + rng.normal(0.0, jitter_px, (int(keep.sum()), 4))
        meta = {**(f.meta or {}), "timestamp": 0.1 * i}
        ids = meta.get("ids_2d")
        if ids is not None and len(ids) == len(keep):
            meta["ids_2d"] = np.asarray(ids)[keep]
        yield replace(f, bboxes_2d=b2.astype(np.float32), match_matrix=None, lidar_time_s=0.1 * i,
                      camera_time_s=0.1 * i, frame_key=str(i), meta=meta)


def _null_site(job) -> dict:
    s, n_base, n, noise = job
    site, base = _synth_stream(s, n_base, **noise)
    return _run(_synth_calibration(site), _replay(base, n, s, 0.5, 0.05), latch=False)


def _null_replay(name: str, seeds: list[int], n_base: int, n: int, log, **noise) -> dict:
    """False alarms on drift-free synthetic streams made cheaply: ``n_base`` generated frames per
    site (``iter_frames``, with ``noise``) replayed with fresh 0.5 px jitter and 5 % extra misses
    per pass to ``n`` frames (the generator costs ~11 ms a frame, the monitor ~2.5 ms)."""
    runs = []
    for s, q in zip(seeds, _pmap(_null_site, [(s, n_base, n, noise) for s in seeds])):
        log(f"  {name}: site {s}: {q['frames']} frames, {q['alarms']} alarms, states {q['states']}, "
            f"{q['cpu_ms']:.2f} ms/frame", flush=True)
        runs.append(q)
    frames_total, alarms, unknown, decisions, cpu = _tally(runs)
    upper = 3.0 / frames_total * 1e4 if alarms == 0 else None  # 95 % upper bound for zero events
    row = {"case": name, "frames": frames_total, "sites": len(seeds), "base_frames_per_site": n_base,
           "false_alarms": alarms, "false_alarms_per_10k": alarms / frames_total * 1e4,
           "upper95_per_10k_if_zero": upper, "unknown_share": unknown / max(decisions, 1),
           "cpu_ms_per_frame": float(np.mean(cpu))}
    log(f"{name:44s} {frames_total:6d} frames  {alarms} false alarms ({row['false_alarms_per_10k']:.2f} per 10k"
        f"{'' if upper is None else f'; 95 % bound {upper:.2f}'})  unknown {100 * row['unknown_share']:.0f} %  "
        f"cpu {row['cpu_ms_per_frame']:.2f} ms/frame")
    return row


def _real_case(name: str, base: list, cal, n_null: int, n_step: int, log, jitter_px: float = 1.0) -> dict:
    """A real sequence looped with jitter (``_replay``): a drift-free stream of ``n_null`` frames
    and each injected step at the middle of ``n_step`` frames (the 3D boxes and points moved)."""
    null = _run(cal, _replay(base, n_null, 1, jitter_px), latch=False)
    out = {"base_frames": len(base), "frames_2d_mean": float(np.mean([f.num_2d for f in base])),
           "frames_3d_mean": float(np.mean([f.num_3d for f in base])),
           "calibration_sigma": [*np.asarray(cal.rotation_std_deg).tolist(), *np.asarray(cal.translation_std_m).tolist()],
           "null": {"frames": n_null, "false_alarms": null["alarms"], "states": null["states"],
                    "weak_axes_decisions": null["weak"], "cpu_ms_per_frame": null["cpu_ms"]}}
    log(f"{name} drift-free, {n_null} frames ({len(base)} looped with {jitter_px:g} px jitter): {null['alarms']} "
        f"alarms, states {null['states']}, weak axes (decisions) {null['weak']}, {null['cpu_ms']:.2f} ms CPU/frame")
    rows = []
    for kind, size, within in STEPS:
        for axis in range(3):
            q = _run(cal, _replay(base, n_step, 2, jitter_px), k0=n_step // 2, change=_change(kind, size, axis))
            rows.append(_summarise(f"{name} step {size:g} {'deg' if kind == 'rotation' else 'm'} {kind} {AXES[axis]}",
                                   [q], kind, size, axis, within, n_step // 2, log))
    out["steps"] = rows
    return out


def _a9(n_null: int, n_step: int, log) -> dict:
    """A9 (16 real frames, yaw-less boxes with their 43k-point clouds: the monitor fits yaw every
    frame) looped with jitter; CPU against ``calibrate`` on a 20-frame window in the same run."""
    from xcalib.calib.api import calibrate
    from xcalib.io.sources import open_source

    seq = open_source(A9)
    raw = [seq[i] for i in range(len(seq))]
    t0 = time.process_time()
    cal = calibrate(raw, None)
    cal_cpu = time.process_time() - t0
    log(f"A9 calibration: {'ok' if cal.success else 'refused'} in {cal_cpu:.1f} s CPU; 1-sigma "
        f"{np.round(cal.rotation_std_deg, 2)} deg {np.round(cal.translation_std_m, 2)} m")
    if not cal.success:
        return {"calibration": cal.message}
    out = _real_case("A9", raw, cal, n_null, n_step, log)
    out["calibration_cpu_s"] = cal_cpu
    win = list(_replay(raw, 20, 3))  # one 20-frame window of the same frames
    t0 = time.process_time()
    calibrate(win, cal.intrinsics)
    cal_win = time.process_time() - t0
    out["cpu"] = {"monitor_ms_per_frame_yawless_boxes": out["null"]["cpu_ms_per_frame"],
                  "calibrate_window_20_frames_s": cal_win, "calibrate_ms_per_frame_of_window": 1e3 * cal_win / 20}
    log(f"A9 CPU (one thread, same run): monitor {out['null']['cpu_ms_per_frame']:.2f} ms/frame with the yaw-less "
        f"boxes (yaw fitted from the 43k-point cloud every frame); calibrate on one 20-frame window {cal_win:.1f} s = "
        f"{1e3 * cal_win / 20:.0f} ms/frame")
    return out


def _rebased(frames: list) -> tuple[list, np.ndarray]:
    """Frames whose ground-truth poses differ (PandaSet's per-frame LiDAR-pose frame, KITTI's
    drives) moved so frame 0's pose ``T0`` projects them as their own pose does:
    3D boxes and points moved by ``T0^-1 T_i``."""
    from xcalib.geometry.transforms import invert_transform
    from xcalib.monitor.inject import move_frame

    T0 = np.asarray(frames[0].extrinsics, dtype=np.float64)
    iT0 = invert_transform(T0)
    return [move_frame(f, iT0 @ np.asarray(f.extrinsics, dtype=np.float64)) for f in frames], T0


def _gt_calibration(frames: list, T0: np.ndarray, name: str):
    from xcalib.calib.result import CalibrationResult

    f = frames[0]
    return CalibrationResult(success=True, intrinsics=f.intrinsics, rotation=T0[:3, :3], translation=T0[:3, 3],
                             rotation_std_deg=np.full(3, 0.1), translation_std_m=np.full(3, 0.05), camera_name=name,
                             image_size=(f.intrinsics.width, f.intrinsics.height))


def _pandaset(n_null: int, n_step: int, log) -> dict:
    """PandaSet 002 (30 frames, real 3D cuboids with track ids and clouds, 1920x1080): 2D boxes
    projected from the cuboids with the ground-truth pose (``synthetic_2d_boxes``: occlusion,
    1 px noise, misses, false boxes; three draws per frame, looped with 0.5 px jitter), the frames rebased to
    frame 0's pose; calibration = that pose (1-sigma 0.1 deg / 5 cm)."""
    root = SHARED / "pandaset_002"
    if not root.exists():
        return {"skipped": f"data not found: {root}"}
    base, cal = _pandaset_base(root)
    return _real_case("PandaSet", base, cal, n_null, n_step, log, jitter_px=0.5)


def _pandaset_base(root: Path) -> tuple[list, object]:
    """``_pandaset``'s frames (three draws of 2D boxes per frame, rebased) and calibration."""
    from xcalib.data.boxes2d import synthetic_2d_boxes
    from xcalib.formats.pandaset import PandaSetFrames

    seq = PandaSetFrames(root, read_images=False)
    frames = [seq[i] for i in range(len(seq))]
    base = []
    for draw in range(3):
        for i, f in enumerate(frames):  # the cloud only for the 2D boxes' visibility (the cuboids carry yaw)
            base.append(replace(synthetic_2d_boxes(f, seed=100 * draw + i), match_matrix=None,
                                point_cloud=np.zeros((0, 3), np.float32)))
    base, T0 = _rebased(base)
    cal = _gt_calibration(base, T0, base[0].camera_name or "front_camera")
    return [replace(f, extrinsics=None, camera_name=cal.camera_name) for f in base], cal


def _kitti(n_null: int, n_step: int, log) -> dict:
    """KITTI (6 labelled frames of different drives, 1-3 objects each: the labels' 2D boxes and
    3D boxes), rebased to frame 0's camera (2D boxes mapped to its intrinsics) and pose;
    calibration = that pose (1-sigma 0.1 deg / 5 cm)."""
    root = SHARED / "kitti" / "openpcdet_pr653" / "training"
    if not root.exists():
        return {"skipped": f"data not found: {root}"}
    base, cal = _kitti_base(root)
    return _real_case("KITTI", base, cal, n_null, n_step, log)


def _kitti_base(root: Path) -> tuple[list, object]:
    """``_kitti``'s frames (one camera, rebased) and calibration."""
    from xcalib.formats.kitti import kitti_frames

    seq = kitti_frames(root)
    frames = [seq[i] for i in range(len(seq))]
    k0 = frames[0].intrinsics
    same = []
    for f in frames:  # one camera: each drive's 2D boxes mapped to frame 0's (rectified pinhole) intrinsics
        k = f.intrinsics
        b2 = np.asarray(f.bboxes_2d, dtype=np.float64).reshape(-1, 4)
        sx, sy = k0.fx / k.fx, k0.fy / k.fy
        b2 = (b2 - [k.cx, k.cy, k.cx, k.cy]) * [sx, sy, sx, sy] + [k0.cx, k0.cy, k0.cx, k0.cy]
        same.append(replace(f, bboxes_2d=b2.astype(np.float32), intrinsics=k0, image=np.zeros((1, 1, 3), np.uint8)))
    base, T0 = _rebased(same)
    cal = _gt_calibration(base, T0, base[0].camera_name or "image_2")
    return [replace(f, extrinsics=None, camera_name=cal.camera_name) for f in base], cal


def _value(v: str):
    """``--set`` value: int, float, bool or str."""
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(v.lower(), v)


def _false_alarms(nulls: dict, null_seeds: list, name: str, replay) -> dict:
    """One noise's false alarms over the drift-free recordings: ``replay(recording)`` gives a
    recording's alarm frames."""
    where = {f"site_{s}": replay(nulls[(name, s)]) for s in null_seeds}
    k = sum(len(a) for a in where.values())
    frames = sum(len(nulls[(name, s)]["rows"]) for s in null_seeds)
    return {"frames": frames, "false_alarms": k, "per_10k_and_90ci": _poisson90(k, frames),
            "alarm_frames": {s: a for s, a in where.items() if a}}


def _replay_setup(args, prefix: str) -> tuple[list, list, tuple, Path]:
    """The replayed parts' null sites, step sites, cells and recordings folder (a fresh temporary
    one unless ``--recordings`` names one)."""
    import tempfile

    nseeds = ([int(v) for v in args.null_seeds.split(",") if v.strip()] if args.null_seeds
              else [3, 5, 7, 11, 13, 17, 19, 23][:args.null_sites])
    sseeds = [int(v) for v in args.step_seeds.split(",") if v.strip()]
    cells = tuple(c for c in args.cells.split(",") if c)
    return nseeds, sseeds, cells, args.recordings or Path(tempfile.mkdtemp(prefix=prefix))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="30-min null streams (18,000 frames per site)")
    ap.add_argument("--sites", type=int, default=3)
    ap.add_argument("--runs", type=int, default=9, help="runs per step size and axis")
    ap.add_argument("--null-frames", type=int, default=1500)
    ap.add_argument("--null-base", type=int, default=1200, help="--part null: generated frames per site (looped)")
    ap.add_argument("--null-sites", type=int, default=6, help="--part null: sites")
    ap.add_argument("--null-seeds", default="", help="--part null: comma-separated site seeds (default: the first --null-sites)")
    ap.add_argument("--null-noise", choices=("both", "default", "noisy"), default="both",
                    help="--part null: which detection noise (two processes can share the work)")
    ap.add_argument("--part", choices=("all", "synth", "a9", "null", "real", "weak", "information", "reference", "bound",
                                       "relin", "relin_a9", "verdict", "persist", "guard", "iterate", "scan",
                                       "pairnoise", "spread"),
                    default="all",
                    help="run one part; its keys are merged into an existing results file")
    ap.add_argument("--reference-frames", type=int, default=2400,
                    help="--part reference: the drift-free reference stretch per site (frames)")
    ap.add_argument("--arms", default="off,online,reference", help="--part reference: the arms to run")
    ap.add_argument("--info-frames", type=int, default=400, help="--part information: frames per site for the bound")
    ap.add_argument("--bound-runs", action="store_true",
                    help="--part bound: also the monitor's own z steps at each site (--runs runs per step)")
    ap.add_argument("--step-seeds", default="3,5,11,17", help="--part relin: the step cells' sites")
    ap.add_argument("--relin-band", type=float, default=0.4,
                    help="--part relin: windows whose statistic reaches this share of the threshold are re-linearised")
    ap.add_argument("--relin-factor", type=float, default=2.0,
                    help="--part relin_a9: the re-linearised test's threshold factor")
    ap.add_argument("--steps-only", action="store_true", help="--part synth: the steps only (no null streams, ramps)")
    ap.add_argument("--real-null", type=int, default=1600, help="real sequences: drift-free frames (looped)")
    ap.add_argument("--real-frames", type=int, default=320, help="real sequences: step streams (change at the middle)")
    ap.add_argument("--recordings", type=Path, default=None,
                    help="--part guard / iterate / scan / spread: folder of the recorded streams (.npz; made when absent; default a temporary one)")
    ap.add_argument("--pair-recordings", type=Path, default=None,
                    help="--part pairnoise: folder of the streams recorded with pair_noise (made when absent)")
    ap.add_argument("--label", default="s14M3", help="--part pairnoise / spread: the results key's suffix")
    ap.add_argument("--quantiles", default="0.75,0.9",
                    help="--part spread: the values of MonitorConfig.difference_quantile replayed beside the default")
    ap.add_argument("--cells", default=",".join(ITERATE_CELLS),
                    help="--part iterate / scan: the step cells (e.g. tz_0.1,rz_0.25: axis and size in deg / m)")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (null sites, step cells)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a MonitorConfig setting other than its default (repeatable; the results say so)")
    ap.add_argument("--out", type=Path, default=None, help="results file (default benchmarks/results/monitor.json)")
    args = ap.parse_args()
    global JOBS
    JOBS = max(1, args.jobs)
    for kv in args.set:
        k, _, v = kv.partition("=")
        CONFIG[k.strip()] = _value(v.strip())
    n_null = 18000 if args.full else args.null_frames
    t_all = time.time()
    def log(*a, **k):
        print(*a, **{"flush": True, **k})

    seeds = [3, 5, 7, 11, 13, 17, 19, 23][:args.sites]
    result = {"machine": machine_info(), "config": "MonitorConfig() defaults"}
    if CONFIG:
        result[f"config_{args.part}"] = dict(CONFIG)
    out = args.out or REPO / "benchmarks" / "results" / "monitor.json"
    argv = [a for i, a in enumerate(sys.argv) if a != "--out" and (i == 0 or sys.argv[i - 1] != "--out")]
    result[f"command_{args.part}" + (f"_{args.null_noise}" if args.part == "null" else "")] = " ".join(argv)
    from _provenance import provenance

    result[f"provenance_{args.part}"] = provenance()  # parts are merged: each keeps the run that made it
    if args.part == "null":  # long drift-free streams (the false-alarm rate), looped with jitter
        nseeds = ([int(v) for v in args.null_seeds.split(",") if v.strip()] if args.null_seeds
                  else [3, 5, 7, 11, 13, 17, 19, 23][:args.null_sites])
        log(f"== long synthetic null streams ({n_null} frames per site from {args.null_base} generated, sites {nseeds})")
        if args.null_noise in ("both", "default"):
            result["null_long_default"] = _null_replay("default noise", nseeds, args.null_base, n_null, log)
        if args.null_noise in ("both", "noisy"):
            result["null_long_noisy"] = _null_replay("4 px box noise, 10 % missed", nseeds, args.null_base, n_null,
                                                     log, box_noise_px=4.0, miss_rate_2d=0.1)
    elif args.part == "bound":  # can any test see a 10 cm z step within 50 frames at these sites?
        bseeds = [int(v) for v in args.null_seeds.split(",") if v.strip()] if args.null_seeds else seeds
        result["bound_s8"] = _bound(bseeds, args.info_frames, log, args.runs if args.bound_runs else 0)
    elif args.part == "relin":  # the re-linearised window test: false alarms and power per threshold factor
        import json

        nseeds = ([int(v) for v in args.null_seeds.split(",") if v.strip()] if args.null_seeds
                  else [3, 5, 7, 11, 13, 17, 19, 23][:args.null_sites])
        sseeds = [int(v) for v in args.step_seeds.split(",") if v.strip()]
        prev = json.loads(out.read_text()) if out.exists() else {}
        log(f"== re-linearised window test (band {args.relin_band:g}): null {n_null} frames x sites {nseeds}, "
            f"z steps at sites {sseeds} ({args.runs} runs)")
        result["relin_s9"] = _relin(nseeds, args.null_base, n_null, sseeds, args.runs, args.relin_band, log,
                                    prev.get("bound_s8"))
    elif args.part == "persist":  # do the frames' errors persist; the test's null from the stream's own spread
        nseeds = ([int(v) for v in args.null_seeds.split(",") if v.strip()] if args.null_seeds
                  else [3, 5, 7, 11, 13, 17, 19, 23][:args.null_sites])
        sseeds = [int(v) for v in args.step_seeds.split(",") if v.strip()]
        log(f"== persistence and the test's null: null {n_null} frames x sites {nseeds}, z steps at {sseeds} "
            f"({args.runs} runs per site)")
        result["persist_s10"] = _persist(nseeds, args.null_base, n_null, sseeds, args.runs, log, args.real_null)
    elif args.part == "guard":  # the inflation's floor with the leave-objects-out guard, replayed on every cell
        import tempfile

        nseeds = ([int(v) for v in args.null_seeds.split(",") if v.strip()] if args.null_seeds
                  else [3, 5, 7, 11, 13, 17, 19, 23][:args.null_sites])
        sseeds = [int(v) for v in args.step_seeds.split(",") if v.strip()]
        folder = args.recordings or Path(tempfile.mkdtemp(prefix="xcalib_guard_"))
        log(f"== the guarded test's variants: null {n_null} frames x sites {nseeds} (both noises), every step cell "
            f"at {sseeds} ({args.runs} runs per site); recordings in {folder}")
        result["guard_s11"] = _guard(nseeds, args.null_base, n_null, sseeds, args.runs, folder, log)
    elif args.part == "iterate":  # the change test on the window's iterated estimate, replayed on every cell
        nseeds, sseeds, cells, folder = _replay_setup(args, "xcalib_iterate_")
        log(f"== the iterated change test: null {n_null} frames x sites {nseeds} (both noises), cells {cells} "
            f"at {sseeds} ({args.runs} runs per site); recordings in {folder}")
        result["iterate_s12"] = _iterate(nseeds, args.null_base, n_null, (sseeds, args.runs, cells), folder, log)
    elif args.part == "scan":  # the change-point scan against the fixed windows, replayed on every cell
        nseeds, sseeds, cells, folder = _replay_setup(args, "xcalib_scan_")
        log(f"== the change-point scan: null {n_null} frames x sites {nseeds} (both noises), cells {cells} "
            f"at {sseeds} ({args.runs} runs per site); recordings in {folder}")
        result["scan_s13"] = _scan_rows(nseeds, args.null_base, n_null, (sseeds, args.runs, cells), folder, log)
    elif args.part == "pairnoise":  # the 3D-box noise weighted per pair against the independent model
        import tempfile

        nseeds, sseeds, cells, folder = _replay_setup(args, "xcalib_pairnoise_")
        pair = args.pair_recordings or Path(tempfile.mkdtemp(prefix="xcalib_pairnoise_pair_"))
        log(f"== the per-pair 3D-box noise: null {n_null} frames x sites {nseeds} (both noises), cells {cells} "
            f"at {sseeds} ({args.runs} runs per site); recordings in {folder} and {pair}")
        result[f"pairnoise_{args.label}"] = _pairnoise(nseeds, args.null_base, n_null, (sseeds, args.runs, cells),
                                                       (folder, pair), log)
    elif args.part == "spread":  # the change test's covariance at the objects' own spread of the difference
        nseeds, sseeds, cells, folder = _replay_setup(args, "xcalib_spread_")
        qs = tuple(float(v) for v in args.quantiles.split(",") if v.strip())
        log(f"== the objects' spread of the difference: quantiles {qs}; null {n_null} frames x sites {nseeds} (both "
            f"noises), cells {cells} at {sseeds} ({args.runs} runs per site); recordings in {folder}")
        result[f"spread_{args.label}"] = _spread(nseeds, args.null_base, n_null, (sseeds, args.runs, cells), folder,
                                                 qs, log)
    elif args.part == "verdict":  # each z step cell against what the boxes allow at its site (no monitor run)
        import json

        log("== each z step cell against the bound at its site")
        result["bound_verdict_s9"] = _verdicts(json.loads(out.read_text()) if out.exists() else {}, log)
    elif args.part == "relin_a9":  # its CPU per frame at A9 density
        log(f"== re-linearised window test at A9 density (band {args.relin_band:g}, x{args.relin_factor:g})")
        result["relin_a9_s9"] = _relin_a9(args.real_null, args.real_frames, args.relin_band, args.relin_factor, log)
    elif args.part == "information":  # is the z step's power the boxes' information or the test?
        result["information"] = _information(seeds, args.info_frames, args.null_frames, log)
    elif args.part in ("all", "synth"):
        _synthetic(result, seeds, n_null, args.runs, log, nulls=not args.steps_only)
    elif args.part == "reference":  # the per-axis calibration of the change test from a reference stretch
        log(f"== per-axis test calibration: {args.reference_frames}-frame reference per site, then steps")
        result["reference_steps"] = _reference(seeds, args.reference_frames, args.null_frames, args.runs, log,
                                               tuple(a for a in args.arms.split(",") if a))
    elif args.part == "weak":  # does the monitor say which changes it cannot see within 50 frames?
        log("== the weak-axes statement: z steps at the size the issue asks for, x as the control")
        streams = {s: _synth_stream(s, n_null) for s in seeds}
        result["weak_statement"] = _steps(streams, args.runs, log, [("translation", 0.10, 50, 2), ("rotation", 0.25, 50, 2),
                                                                    ("translation", 0.10, 50, 0)])
    if args.part in ("all", "a9") and A9.exists():
        log("\n== A9 (16 real frames looped with jitter, injected drift)")
        result["a9"] = _a9(args.real_null, args.real_frames, log)
    if args.part in ("all", "real"):
        log("\n== PandaSet 002 (30 real frames x 3 draws of projected 2D boxes, looped, injected drift)")
        result["pandaset"] = _pandaset(args.real_null, args.real_frames, log)
        log("\n== KITTI (6 labelled frames looped with jitter, injected drift)")
        result["kitti"] = _kitti(args.real_null, args.real_frames, log)
    result[f"wall_s_{args.part}" + (f"_{args.null_noise}" if args.part == "null" else "")] = time.time() - t_all
    if args.part != "all" and out.exists():  # merged at write time: the other part may have finished meanwhile
        import json

        result = {**json.loads(out.read_text()), **result}
    write_result(out, result)


def _information(seeds: list[int], n_bound: int, n_null: int, log) -> dict:
    """Per site: the Cramer-Rao bound of each axis over 40 / 50 frames and the power the 6-dof test
    would have with it for the target steps (``monitor_information``), beside the monitor's own
    test on a drift-free stream (stated vs empirical spread)."""
    from monitor_information import bound_rows, frame_information, monitor_spread, sequential_rows

    from xcalib.monitor import Monitor, MonitorConfig

    cfg = MonitorConfig()
    rows = {}
    for s in seeds:
        site, frames = _synth_stream(s, max(n_bound, n_null))
        cal = _synth_calibration(site)
        cm = next(iter(Monitor(cal, cfg).cameras.values()))
        infos = frame_information(cm, frames[:n_bound], float(site.config.box_noise_px))
        row = {"bound": bound_rows(infos, cfg.threshold), "monitor": monitor_spread(cal, frames[:n_null]),
               "sequential": sequential_rows(infos, cfg.false_alarm_rate, cfg.stride)}
        for key, q in row["sequential"].items():
            log(f"site {s} {key} (bound's information, last decision within the frames): fixed windows "
                f"{q['fixed']:.2f}, + a window of the target's length {q['fixed_plus_target']:.2f}, GLR over every "
                f"change point in the last 80 frames {q['glr_scan']:.2f}")
        rows[f"site_{s}"] = row
        for L, b in row["bound"].items():
            sd = b["sigma_per_axis"]
            log(f"site {s} {L}: bound 1-sigma rot {np.round(sd[:3], 3)} deg, trans {np.round(np.array(sd[3:]) * 100, 2)} cm; "
                f"6-dof test power for 0.25 deg / 10 cm: " + ", ".join(f"{a} {v:.2f}" for a, v in b["power_6dof_target_step"].items()))
        m = row["monitor"]
        log(f"site {s} monitor (40 vs 250 frames, {m['tests']} tests): mean chi2 {m['mean_chi2_6dof']:.2f} (6: covariance right); "
            f"stated / empirical variance " + ", ".join(f"{a} {v:.2f}" for a, v in m["stated_over_empirical_variance"].items())
            + f"; detectable tz {100 * m['detectable_tz_median_m']:.1f} cm")
        for key, w in m["by_window"].items():
            log(f"site {s}   {key:16s} ({w['tests']} tests vs 250 frames): mean chi2 {w['mean_chi2_6dof']:.2f}, max "
                f"{w['max_chi2_6dof']:.1f}, above the 1 % point {100 * w['share_above_chi2_6dof_1pct']:.1f} %; stated / "
                "empirical variance " + ", ".join(f"{a} {v:.2f}" for a, v in w["stated_over_empirical_variance"].items()))
    return rows


def _bound(seeds: list[int], n: int, log, runs: int = 0) -> dict:
    """The Cramer-Rao bound of the issue's steps and the power of efficient tests at the
    false-alarm rate (``monitor_information.efficient_rows``), per synthetic site and for A9's
    16 real frames (looped: their geometry under the generator's noise), beside each site's
    geometry (``site_geometry``): is ">= 95 % within 50 frames" possible with boxes alone, and
    are the benchmark's sites like a real roadside site? ``runs`` > 0: beside the bound, the
    monitor's own 10 cm / 50-frame and 20 cm / 20-frame z steps at each site (``runs`` runs each,
    from frame 250 of an 800-frame stream, as ``--part synth``)."""
    from monitor_information import efficient_rows, frame_information, sequential_rows, site_geometry

    from xcalib.monitor import Monitor, MonitorConfig

    cfg = MonitorConfig()
    targets = ((5, 0.10, 50), (5, 0.20, 20), (3, 0.10, 50), (4, 0.10, 50), (2, np.radians(0.25), 50))
    rows = {}

    def show(name, row):
        g = row["geometry"]
        log(f"{name}: {g['pairs_per_frame']:.1f} pairs/frame, depth median {g['depth_m_median']:.1f} m "
            f"(10-90 % {g['depth_m_p10_p90'][0]:.0f}-{g['depth_m_p10_p90'][1]:.0f}), spread/frame "
            f"{g['depth_spread_per_frame_m_median']:.0f} m, |x/z| {g['off_axis_lever_median']:.2f}, camera "
            f"{g['camera_height_m']:.1f} m high, pitch {g['camera_pitch_down_deg']:.1f} deg down")
        for key, q in row["sequential"].items():
            log(f"  {key:22s} change time unknown (the decision within the frames): the monitor's windows "
                f"{q['fixed']:.2f}, + a target-length window {q['fixed_plus_target']:.2f}, GLR scan {q['glr_scan']:.2f}")
        for key, q in row["efficient"].items():
            log(f"  {key:22s} CRB 1-sigma {q['crb_sigma_median']:.4f} (two-sample {q['two_sample_sigma_median']:.4f}); "
                f"power: 6-dof {q['power_6dof']:.2f}, per-axis 1-dof {q['power_axes_1dof']:.2f}, oracle 1-dof "
                f"{q['power_oracle_1dof']:.2f} (placements >= 0.95: {100 * q['share_oracle_ge_95']:.0f} %)")

    for s in seeds:
        site, frames = _synth_stream(s, max(n, 800 if runs else 0))
        cm = next(iter(Monitor(_synth_calibration(site), cfg).cameras.values()))
        infos = frame_information(cm, frames[:n], float(site.config.box_noise_px))
        rows[f"site_{s}"] = {"geometry": site_geometry(cm, frames[:100], site.T_world_cam),
                             "efficient": efficient_rows(infos, cfg.false_alarm_rate, cfg.stride, targets=targets),
                             "sequential": sequential_rows(infos, cfg.false_alarm_rate, cfg.stride)}
        show(f"site {s}", rows[f"site_{s}"])
        if runs:
            rows[f"site_{s}"]["monitor_steps"] = _steps({s: (site, frames)}, runs,
                                                        lambda m, **k: log(f"  site {s} monitor: {m}", **k),
                                                        [("translation", 0.10, 50, 2), ("translation", 0.20, 20, 2)])
    if A9.exists():
        from xcalib.calib.api import calibrate
        from xcalib.io.sources import open_source

        seq = open_source(A9)
        raw = [seq[i] for i in range(len(seq))]
        cal = calibrate(raw, None)
        if cal.success:
            cm = next(iter(Monitor(cal, cfg).cameras.values()))
            base = frame_information(cm, raw, 2.0)
            infos = base[np.arange(n) % len(base)]
            rows["a9"] = {"geometry": site_geometry(cm, raw),
                          "efficient": efficient_rows(infos, cfg.false_alarm_rate, cfg.stride, targets=targets),
                          "sequential": sequential_rows(infos, cfg.false_alarm_rate, cfg.stride),
                          "note": "16 real frames looped; the generator's noise (2 px, 0.1 m centre, 3 % size, 2 deg yaw) "
                                  "as if fresh every frame; pose = calibrate on the 16 frames"}
            show("A9", rows["a9"])
            nm = cal.diagnostics.noise_model if cal.diagnostics is not None else None
            if nm is not None:  # the same frames under the noise calibrate fitted to their boxes
                sig = np.array([nm.sigma_3d_m] * 3 + [nm.sigma_size] * 3 + [np.radians(2.0)])
                base = frame_information(cm, raw, float(nm.sigma_px), sig)
                infos = base[np.arange(n) % len(base)]
                rows["a9_fitted_noise"] = {
                    "geometry": rows["a9"]["geometry"], "noise_model": nm._asdict(),
                    "efficient": efficient_rows(infos, cfg.false_alarm_rate, cfg.stride, targets=targets),
                    "sequential": sequential_rows(infos, cfg.false_alarm_rate, cfg.stride),
                    "note": "A9's 16 frames under the noise model calibrate fitted to them (3D centre, size; "
                            "2 deg yaw), as if fresh every frame"}
                show(f"A9 (fitted noise: {nm.sigma_px:.1f} px, {nm.sigma_3d_m:.2f} m, {100 * nm.sigma_size:.0f} %)",
                     rows["a9_fitted_noise"])
    return rows


RELIN_FACTORS = (1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 3.0)
RELIN_CELLS = [("translation", 0.10, 50, 2), ("translation", 0.20, 20, 2)]
RELIN_GAP = 100  # frames: exceedances closer than this to the last alarm are the same alarm (the monitor restarts)
RECORD_ONLY = 1e6  # relinearise_factor that records the re-linearised statistics and never alarms on them


def _alarm_frames(q: dict, factor: float | None) -> list[int]:
    """The alarm frames of one recorded run (``relinearise_factor`` = RECORD_ONLY) as the monitor
    with the re-linearised window test at ``factor`` times the threshold would raise them: its own
    alarms and the frames whose re-linearised statistic exceeds ``factor * threshold``, merged
    within RELIN_GAP frames (None: the monitor without the test). An upper bound: the recorded
    exceedances skip the leave-out guard, which only removes alarms."""
    ev = list(q["alarm_frames"])
    if factor is not None:
        ev += [int(t[0]) - 1 for t in q["relin"] if t[3] > factor * q["threshold"]]
    out: list[int] = []
    for e in sorted(ev):
        if not out or e - out[-1] > RELIN_GAP:
            out.append(e)
    return out


def _relin_steps(res: list[dict], factor: float | None, within: int) -> dict:
    firsts = []
    for q in res:
        a = _alarm_frames(q, factor)
        firsts.append(a[0] if a else None)
    early = sum(1 for f in firsts if f is not None and f < PRE)
    return {"detected_within": float(np.mean([f is not None and PRE <= f and f - PRE <= within for f in firsts])),
            "alarm_before_change": early}


def bound_verdict(bound: dict, detected: float, key: str, runs: int) -> dict:
    """One step cell against what the boxes allow (``--part bound``'s rows of the site): ``impossible``
    where even an efficient 6-dof test that knows when the change happened stays below 95 %
    power at the false-alarm rate (``efficient``: the Cramer-Rao bound of the generator's boxes;
    optimistic), ``detected`` where the monitor reached 95 % of ``runs``, else ``possible`` (the
    information is there; the monitor does not reach it). Also the oracle (direction and time
    known) and the best of the monitor's fixed windows with the time unknown (``sequential``)."""
    e, q = bound.get("efficient", {}).get(key), bound.get("sequential", {}).get(key)
    p6 = None if e is None else float(e["power_6dof"])
    verdict = ("unknown" if p6 is None else "impossible" if p6 < 0.95 else
               "detected" if detected >= 0.95 else "possible")
    return {"verdict": verdict, "monitor": detected, "runs": runs, "bound_6dof_time_known": p6,
            "bound_oracle": None if e is None else float(e["power_oracle_1dof"]),
            "bound_fixed_windows_time_unknown": None if q is None else float(q["fixed"]),
            "crb_sigma_m": None if e is None else float(e["crb_sigma_median"])}


def _relin(null_seeds: list[int], n_base: int, n_null: int, step_seeds: list[int], runs: int, band: float,
           log, bound: dict | None = None) -> dict:
    """The re-linearised window test (``MonitorConfig.relinearise_band``), measured: the monitor
    records, without alarming on them (``relinearise_factor`` = RECORD_ONLY), the re-linearised
    statistic of every window whose statistic reaches ``band`` times the threshold on the long
    null streams (default and noisy, as ``--part null``) and on the z step cells (``RELIN_CELLS``
    at ``step_seeds``, as ``--part synth``); then, per factor on the threshold (RELIN_FACTORS),
    the false alarms it would add (``_alarm_frames``) and the detection rate it would reach,
    beside the monitor without it (its own alarms in the same runs), and each cell's verdict
    against the bound (``bound_verdict``; ``bound``: ``--part bound``'s rows)."""
    CONFIG.update({"relinearise_band": band, "relinearise_factor": RECORD_ONLY})
    out: dict = {"band": band, "factors": list(RELIN_FACTORS), "null": {}, "steps": {}}
    factors: list[float | None] = [None, *RELIN_FACTORS]
    for name, noise in (("default", {}), ("noisy", {"box_noise_px": 4.0, "miss_rate_2d": 0.1})):
        runs_n = [q for q in _pmap(_null_site, [(s, n_base, n_null, noise) for s in null_seeds])]
        frames = sum(q["frames"] for q in runs_n)
        fa = {("off" if f is None else f"x{f:g}"): sum(len(_alarm_frames(q, f)) for q in runs_n) for f in factors}
        tr = [t for q in runs_n for t in q["relin"]]
        ratio = [t[3] / t[2] for t in tr if t[2] > 0]
        out["null"][name] = {"frames": frames, "sites": null_seeds, "false_alarms": fa,
                             "relinearised_tests": len(tr), "ratio_median": _pct(ratio),
                             "ratio_p90": float(np.quantile(ratio, 0.9)) if ratio else None,
                             "max_relinearised_over_threshold": max((t[3] / q["threshold"] for q in runs_n
                                                                     for t in q["relin"]), default=0.0),
                             "cpu_ms_per_frame": float(np.mean([q["cpu_ms"] for q in runs_n]))}
        log(f"null {name}: {frames} frames, {len(tr)} re-linearised tests (ratio median {_f(_pct(ratio), 2)}), "
            f"false alarms " + ", ".join(f"{k} {v}" for k, v in fa.items())
            + f"; cpu {out['null'][name]['cpu_ms_per_frame']:.2f} ms/frame", flush=True)
    for s in step_seeds:
        site, frames = _synth_stream(s, 800)
        _STREAMS.clear()
        _STREAMS[s] = (site, frames)
        for cell in RELIN_CELLS:
            kind, size, within, axis = cell
            res = _step_runs((*cell, runs))
            key = f"t{AXES[axis]}_{size:g}_within_{within}"
            row = {("off" if f is None else f"x{f:g}"): _relin_steps(res, f, within) for f in factors}
            tr = [t for q in res for t in q["relin"] if t[0] - 1 >= PRE]
            base = _summarise(f"site {s} step {size:g} m z (monitor without the test)", res, kind, size, axis, within,
                              PRE, log)
            cellrow = {"by_factor": row, "monitor": base,
                       "ratio_after_change_median": _pct([t[3] / t[2] for t in tr if t[2] > 0])}
            if bound and f"site_{s}" in bound:
                cellrow["bound"] = bound_verdict(bound[f"site_{s}"], base["detected_within"], key, runs)
            out["steps"][f"site_{s}_{key}"] = cellrow
            log(f"  site {s} {key}: within {within}: " + ", ".join(
                f"{k} {100 * v['detected_within']:.0f} %" + (f" ({v['alarm_before_change']} early)"
                                                            if v["alarm_before_change"] else "")
                for k, v in row.items()) + f"; ratio after the change {_f(cellrow['ratio_after_change_median'], 2)}"
                + (f"; bound: {cellrow['bound']['verdict']} (6-dof time known {cellrow['bound']['bound_6dof_time_known']:.2f})"
                   if "bound" in cellrow else ""), flush=True)
    return out


PERSIST_CELLS = [("translation", 0.10, 50, 2), ("translation", 0.20, 20, 2)]


def _persist_null(job) -> dict:
    """One drift-free stream (``_null_site``'s): the monitor's frames recorded once
    (``monitor_persistence.collect``), their persistence measured on the generated (not yet
    looped) frames, and every variant of the change test replayed on the whole stream."""
    import monitor_persistence as mp

    s, n_base, n, noise = job
    site, base = _synth_stream(s, n_base, **noise)
    d = mp.collect(_synth_calibration(site), _replay(base, n, s, 0.5, 0.05))
    head = {k: (v[:n_base] if k in ("H", "g", "c", "n_res", "objects") else v) for k, v in d.items()}
    fig = mp.analyse(head)
    alarms, phis = {}, {}
    for name, kw in mp.VARIANTS.items():
        alarms[name], phis[name] = mp.null_alarms(d["rows"], d["cov_cal"], d["threshold"], **kw)
    return {"frames": len(d["rows"]), "persistence": fig, "alarms": alarms, "inflation_median": phis,
            "cpu_ms": d["cpu_ms"]}


def _persist_steps(job) -> dict:
    """One site's z step runs: each recorded once (no alarm may move the linearisation), each
    variant's first detection replayed."""
    import monitor_persistence as mp
    from xcalib.monitor.inject import inject_change

    s, runs = job
    site, frames = _synth_stream(s, PRE + POST + 137 * max(runs - 1, 0) + 1)
    cal = _synth_calibration(site)
    out = {}
    for kind, size, within, axis in PERSIST_CELLS:
        r_, t_ = _change(kind, size, axis)
        res = {name: [] for name in mp.VARIANTS}
        for r in range(runs):
            k0 = PRE + r * 137
            seg = [inject_change(f, cal, r_, t_) if i >= PRE else f for i, f in enumerate(frames[k0 - PRE:k0 + POST])]
            d = mp.collect(cal, seg)
            for name, kw in mp.VARIANTS.items():
                res[name].append(mp.first_detection(d["rows"], d["cov_cal"], d["threshold"], **kw))
        out[f"t{AXES[axis]}_{size:g}_within_{within}"] = res
    return out


def _persist(null_seeds: list[int], n_base: int, n_null: int, step_seeds: list[int], runs: int, log,
             real_frames: int = 0) -> dict:
    """Do the monitor's per-frame errors persist over frames, and does a test that uses the
    stream's own spread (the inflation's floor lowered, or a factor on the covariance) keep the
    false-alarm rate while detecting more z steps? (``monitor_persistence``: the persistence
    figures; the variants replayed offline on the same recorded frames.)"""
    import monitor_persistence as mp

    out = {"variants": {k: dict(v) for k, v in mp.VARIANTS.items()}, "null": {}, "persistence": {}, "steps": {},
           "note": "variants replayed from the recorded frames without the leave-objects-out guard "
                   "(which only removes alarms): their false alarms are upper bounds; 'default' is the monitor's test"}
    for name, noise in (("default", {}), ("noisy", {"box_noise_px": 4.0, "miss_rate_2d": 0.1})):
        tot = dict.fromkeys(mp.VARIANTS, 0)
        per_site, frames = {}, 0
        for s, q in zip(null_seeds, _pmap(_persist_null, [(s, n_base, n_null, noise) for s in null_seeds])):
            frames += q["frames"]
            for v in tot:
                tot[v] += q["alarms"][v]
            per_site[f"site_{s}"] = {"alarms": q["alarms"], "inflation_median": q["inflation_median"]}
            out["persistence"][f"site_{s}_{name}"] = q["persistence"]
            mp._print(f"site {s} {name}", q["persistence"], log)
            log(f"  site {s} {name}: {q['frames']} frames; alarms per variant {q['alarms']}; inflation "
                + " ".join(f"{k} {v:.2f}" for k, v in q["inflation_median"].items()), flush=True)
        out["null"][name] = {"frames": frames, "sites": null_seeds, "alarms": tot,
                             "alarms_per_10k": {k: v / frames * 1e4 for k, v in tot.items()}, "per_site": per_site}
        log(f"== null {name}: {frames} frames; false alarms per variant {tot}")
    cells: dict = {}
    for s, q in zip(step_seeds, _pmap(_persist_steps, [(s, runs) for s in step_seeds])):
        for cell, res in q.items():
            within = int(cell.rsplit("_", 1)[1])
            for v, firsts in res.items():
                c = cells.setdefault(cell, {}).setdefault(v, {"runs": 0, "detected_within": 0, "early": 0, "per_site": {}})
                hits = [f is not None and 0 <= f - PRE <= within for f in firsts]
                c["runs"] += len(firsts)
                c["detected_within"] += sum(hits)
                c["early"] += sum(f is not None and f < PRE for f in firsts)
                c["per_site"][f"site_{s}"] = float(np.mean(hits))
    for cell, byv in cells.items():
        for v, c in byv.items():
            c["detected_within"] = c["detected_within"] / max(c["runs"], 1)
        log(f"{cell}: " + "; ".join(f"{v} {c['detected_within'] * 100:.0f} % (early {c['early']}; "
                                    + " ".join(f"{k[5:]} {x * 100:.0f}" for k, x in c["per_site"].items()) + ")"
                                    for v, c in byv.items()))
    out["steps"] = cells
    out["runs_per_site"] = runs
    if real_frames:
        out["real"] = mp.real(real_frames, log)
    return out


GUARD_NOISES = (("default", {}), ("noisy", {"box_noise_px": 4.0, "miss_rate_2d": 0.1}))


def _guard_record(job) -> str:
    """One recording of ``--part guard`` (``monitor_persistence.collect``, saved as ``.npz`` in the
    recordings folder; reused when there): a drift-free stream (``_null_site``'s frames) or one
    site's step runs of one cell (``_persist_steps``'s segments)."""
    import monitor_persistence as mp
    from xcalib.monitor.inject import inject_change

    folder, kind = job[0], job[1]
    if kind == "null":
        _, _, noise_name, s, n_base, n = job[:6]
        path = folder / f"null_{noise_name}_{s}.npz"
        if not path.exists():
            site, base = _synth_stream(s, n_base, **dict(GUARD_NOISES)[noise_name])
            mp.save_recording(path, mp.collect(_synth_calibration(site), _replay(base, n, s, 0.5, 0.05),
                                               config=_recording_config(job[6] if len(job) > 6 else None)))
        return str(path)
    _, _, s, runs = job
    todo = [(k, size, axis, r) for k, size, _ in STEPS for axis in range(3) for r in range(runs)
            if not (folder / f"step_{k[0]}{AXES[axis]}_{size:g}_{s}_{r}.npz").exists()]
    if todo:
        site, frames = _synth_stream(s, PRE + POST + 137 * max(runs - 1, 0) + 1)
        cal = _synth_calibration(site)
        for k, size, axis, r in todo:
            r_, t_ = _change(k, size, axis)
            k0 = PRE + r * 137
            seg = [inject_change(f, cal, r_, t_) if i >= PRE else f for i, f in enumerate(frames[k0 - PRE:k0 + POST])]
            mp.save_recording(folder / f"step_{k[0]}{AXES[axis]}_{size:g}_{s}_{r}.npz", mp.collect(cal, seg))
    return str(folder)


def _poisson90(k: int, n: int) -> list[float]:
    """k events in n frames: the rate per 10,000 frames and its 90 % Poisson interval."""
    from scipy.stats import chi2

    lo = 0.0 if k == 0 else float(chi2.ppf(0.05, 2 * k)) / 2
    return [1e4 * k / n, 1e4 * lo / n, 1e4 * float(chi2.ppf(0.95, 2 * k + 2)) / 2 / n]


def _guard(null_seeds: list[int], n_base: int, n_null: int, step_seeds: list[int], runs: int, folder: Path,
           log) -> dict:
    """The change test's variants with the leave-objects-out guard (``monitor_persistence.GUARD_VARIANTS``:
    the inflation's floor, the objects left out), replayed (``monitor_persistence.replay``: the
    monitor's decisions and alarms, the guard included) on recordings of the long null streams (as
    ``--part null``, both noises) and of every step cell (rotation and translation, each axis, the
    issue's four sizes; ``runs`` segments per ``step_seeds`` site, as ``--part persist``): false
    alarms per 10,000 frames with their 90 % Poisson interval, the share of runs detected within
    50 / 20 frames, alarms before the change. The recordings are ``folder``'s ``.npz`` files
    (made when absent)."""
    import monitor_persistence as mp

    folder.mkdir(parents=True, exist_ok=True)
    jobs = [(folder, "null", name, s, n_base, n_null) for name, _ in GUARD_NOISES for s in null_seeds]
    jobs += [(folder, "steps", s, runs) for s in step_seeds]
    for done in _pmap(_guard_record, jobs):
        log(f"  recorded {done}", flush=True)
    variants = mp.GUARD_VARIANTS
    out: dict = {"variants": {k: dict(v) for k, v in variants.items()}, "null": {}, "steps": {},
                 "null_seeds": null_seeds, "step_seeds": step_seeds, "runs_per_site": runs,
                 "note": "replayed from recordings of the default monitor's frames (the replay reproduces the "
                         "monitor's alarm frames, guard included); false alarms: the history forgotten after each"}
    for name, _ in GUARD_NOISES:
        recs = {s: mp.load_recording(folder / f"null_{name}_{s}.npz") for s in null_seeds}
        frames = sum(len(r["rows"]) for r in recs.values())
        for v, kw in variants.items():
            where = {f"site_{s}": mp.replay(r, **kw) for s, r in recs.items()}
            k = sum(len(a) for a in where.values())
            out["null"][f"{name}/{v}"] = {"frames": frames, "false_alarms": k, "per_10k_and_90ci": _poisson90(k, frames),
                                          "alarm_frames": {s: a for s, a in where.items() if a}}
            log(f"null {name:7s} {v:16s} {frames} frames: {k} false alarms, per 10k "
                + " ".join(f"{x:.2f}" for x in _poisson90(k, frames)) + f"  {out['null'][f'{name}/{v}']['alarm_frames']}",
                flush=True)
    for kind, size, within in STEPS:
        for axis in range(3):
            cell = f"{kind[0]}{AXES[axis]}_{size:g}_within_{within}"
            recs = [(s, mp.load_recording(folder / f"step_{kind[0]}{AXES[axis]}_{size:g}_{s}_{r}.npz"))
                    for s in step_seeds for r in range(runs)]
            for v, kw in variants.items():
                firsts = [(mp.replay(rec, first_only=True, **kw) or [None])[0] for _, rec in recs]
                delays = [None if f is None else f - PRE for f in firsts]
                hits = [d is not None and 0 <= d <= within for d in delays]
                row = {"runs": len(hits), "detected_within": float(np.mean(hits)),
                       "early": sum(d is not None and d < 0 for d in delays), "delays": delays,
                       "missed_sites": sorted({s for (s, _), h in zip(recs, hits) if not h})}
                out["steps"][f"{cell}/{v}"] = row
                log(f"{cell:24s} {v:16s} {100 * row['detected_within']:5.1f} % of {row['runs']} (early {row['early']}; "
                    f"missed at sites {row['missed_sites']})", flush=True)
    return out


#: ``--part iterate``'s default cells: the ones the one-step test misses (z, roll) and an x control each
ITERATE_CELLS = ("tz_0.1", "rz_0.25", "tz_0.2", "rz_0.5", "tx_0.1", "rx_0.25")
#: its variants (``monitor_persistence.replay``'s ``iterate``: Gauss-Newton steps; -1 the one-step default)
ITERATE_VARIANTS = {"one-step (default)": -1, "iterated 1": 1, "iterated 3": 3}
ITERATE_FACTORS = (1.0, 1.5, 2.0, 2.5, 3.0)  # on the threshold and the guard's leave-out threshold


def _cell_record(job) -> str:
    """One site's step runs of the given cells (``_guard_record``'s segments and file names), recorded
    with the frames' unshaped residual rows."""
    import monitor_persistence as mp
    from xcalib.monitor.inject import inject_change

    folder, s, runs, cells = job[:4]
    cfg = _recording_config(job[4] if len(job) > 4 else None)
    todo = [(c, r) for c in cells for r in range(runs)
            if not (folder / f"step_{c.split('_')[0]}_{float(c.split('_')[1]):g}_{s}_{r}.npz").exists()]
    if todo:
        site, frames = _synth_stream(s, PRE + POST + 137 * max(runs - 1, 0) + 1)
        cal = _synth_calibration(site)
        for c, r in todo:
            name, size = c.split("_")
            r_, t_ = _change("rotation" if name[0] == "r" else "translation", float(size), AXES.index(name[1]))
            k0 = PRE + r * 137
            seg = [inject_change(f, cal, r_, t_) if i >= PRE else f for i, f in enumerate(frames[k0 - PRE:k0 + POST])]
            mp.save_recording(folder / f"step_{name}_{float(size):g}_{s}_{r}.npz", mp.collect(cal, seg, config=cfg))
    return f"{folder} site {s}"


def _recording_config(settings: dict | None):
    """The recording monitor's config: ``monitor_persistence.collect``'s default (None), or that one
    (no alarm: a rate of 1e-12) with ``settings`` (MonitorConfig fields that change the frames' rows,
    e.g. ``pair_noise``)."""
    from xcalib.monitor import MonitorConfig

    return None if not settings else MonitorConfig(latch=True, false_alarm_rate=1e-12, **settings)


def _iterate(null_seeds: list[int], n_base: int, n_null: int, steps: tuple, folder: Path, log) -> dict:
    """The change test on each window's estimate iterated by Gauss-Newton steps on the frames' unshaped
    residual rows (``MonitorConfig.iterate_steps``; ``monitor_persistence.replay(iterate=)``, the guard
    included) against the one-step default, on recordings of the long null streams (both noises, as
    ``--part guard``) and of the step cells ``steps`` = (sites, runs per site, cells): per variant and
    factor on the threshold, false alarms (90 % Poisson interval) and runs detected within the cell's
    target frames. The recordings are ``folder``'s ``.npz`` files (made when absent; they need the
    unshaped rows, which recordings before session 12 lack)."""
    import monitor_persistence as mp
    from xcalib.monitor import MonitorConfig
    from xcalib.monitor import stats as mstats

    step_seeds, runs, cells = steps
    folder.mkdir(parents=True, exist_ok=True)
    jobs = [(folder, "null", name, s, n_base, n_null) for name, _ in GUARD_NOISES for s in null_seeds]
    for done in [*_pmap(_guard_record, jobs), *_pmap(_cell_record, [(folder, s, runs, cells) for s in step_seeds])]:
        log(f"  recorded {done}", flush=True)
    cfg = MonitorConfig()
    h, h_out = cfg.threshold, mstats.threshold(cfg.leave_out_level, 1, 1)
    within = {"r": {0.25: 50, 0.5: 20}, "t": {0.1: 50, 0.2: 20}}
    out: dict = {"variants": dict(ITERATE_VARIANTS), "factors": list(ITERATE_FACTORS), "rows": {},
                 "null_seeds": null_seeds, "step_seeds": step_seeds, "runs_per_site": runs, "cells": list(cells),
                 "note": "replayed from recordings (the replay raises the monitor's alarms, guard included); the factor "
                         "multiplies the threshold and the guard's leave-out threshold; false alarms: the history "
                         "forgotten after each"}
    nulls = {(name, s): mp.load_recording(folder / f"null_{name}_{s}.npz") for name, _ in GUARD_NOISES for s in null_seeds}
    recs = {c: [(s, mp.load_recording(folder / f"step_{c.split('_')[0]}_{float(c.split('_')[1]):g}_{s}_{r}.npz"))
                for s in step_seeds for r in range(runs)] for c in cells}
    for v, it in ITERATE_VARIANTS.items():
        for fac in ITERATE_FACTORS:
            row = {name: _false_alarms(nulls, null_seeds, name,
                                       lambda rec: mp.replay(rec, iterate=it, threshold=h * fac, h_out=h_out * fac))
                   for name, _ in GUARD_NOISES}
            for c in cells:
                lim = within[c[0]][float(c.split("_")[1])]
                firsts = [(mp.replay(rec, iterate=it, threshold=h * fac, h_out=h_out * fac, first_only=True)
                           or [None])[0] for _, rec in recs[c]]
                delays = [None if f is None else f - PRE for f in firsts]
                hits = [d is not None and 0 <= d <= lim for d in delays]
                row[c] = {"runs": len(hits), "detected_within": int(sum(hits)), "within_frames": lim,
                          "early": sum(d is not None and d < 0 for d in delays), "delays": delays,
                          "missed_sites": sorted({s for (s, _), hit in zip(recs[c], hits) if not hit})}
            out["rows"][f"{v}/x{fac:g}"] = row
            log(f"{v:20s} x{fac:<4g} false alarms {row['default']['false_alarms']} / {row['noisy']['false_alarms']}  "
                + "  ".join(f"{c} {row[c]['detected_within']}/{row[c]['runs']}" + (f" (early {row[c]['early']})"
                                                                                  if row[c]['early'] else "")
                            for c in cells), flush=True)
    return out


def _iterate_recordings(null_seeds: list[int], n_base: int, n_null: int, steps: tuple, folder: Path, log):
    """The recordings of ``--part iterate`` in ``folder`` (made when absent), loaded: (each cell's target
    delay per axis and size, the null streams by (noise, seed), each cell's step streams as (seed, recording))."""
    import monitor_persistence as mp

    step_seeds, runs, cells = steps
    folder.mkdir(parents=True, exist_ok=True)
    jobs = [(folder, "null", name, s, n_base, n_null) for name, _ in GUARD_NOISES for s in null_seeds]
    for done in [*_pmap(_guard_record, jobs), *_pmap(_cell_record, [(folder, s, runs, cells) for s in step_seeds])]:
        log(f"  recorded {done}", flush=True)
    within = {"r": {0.25: 50, 0.5: 20}, "t": {0.1: 50, 0.2: 20}}
    nulls = {(name, s): mp.load_recording(folder / f"null_{name}_{s}.npz") for name, _ in GUARD_NOISES for s in null_seeds}
    recs = {c: [(s, mp.load_recording(folder / f"step_{c.split('_')[0]}_{float(c.split('_')[1]):g}_{s}_{r}.npz"))
                for s in step_seeds for r in range(runs)] for c in cells}
    return within, nulls, recs


def _scan_rows(null_seeds: list[int], n_base: int, n_null: int, steps: tuple, folder: Path, log) -> dict:
    """The change-point scan (``MonitorConfig.change_point_step`` = 5: every recent segment of 10, 15, ..., 80
    frames against the frames before it, the threshold from the scan's simulated null) against the
    fixed 20 / 40 / 80-frame windows, replayed (``monitor_persistence.replay``, the guard included)
    on the recordings of ``--part iterate`` (made when absent): false alarms on the long null streams
    (both noises) and runs detected within the cell's target per cell, each at its own threshold and
    the scan also at the thresholds where its false alarms equal the fixed windows' (``SCAN_THRESHOLDS``:
    an oracle read off the nulls)."""
    import monitor_persistence as mp
    from xcalib.monitor import MonitorConfig

    step_seeds, runs, cells = steps
    within, nulls, recs = _iterate_recordings(null_seeds, n_base, n_null, steps, folder, log)
    fixed, scan = MonitorConfig(latch=False), MonitorConfig(latch=False, change_point_step=5)
    variants = [("fixed windows (default)", fixed, fixed.threshold), ("scan 5", scan, scan.threshold)]
    variants += [(f"scan 5 at {h:g}", scan, h) for h in SCAN_THRESHOLDS]
    out: dict = {"rows": {}, "null_seeds": null_seeds, "step_seeds": step_seeds, "runs_per_site": runs,
                 "cells": list(cells), "scan_windows": list(scan.test_windows),
                 "thresholds": {"fixed": fixed.threshold, "scan": scan.threshold},
                 "note": "replayed from recordings (the replay raises the monitor's alarms, guard included); false "
                         "alarms: the history forgotten after each; 'scan 5 at h': the scan at a threshold read off "
                         "the null streams (an oracle)"}
    for v, cfg, h in variants:
        row: dict = {"threshold": h}
        for name, _ in GUARD_NOISES:
            row[name] = _false_alarms(nulls, null_seeds, name, lambda rec: mp.replay(rec, config=cfg, threshold=h))
        for c in cells:
            lim = within[c[0]][float(c.split("_")[1])]
            firsts = [(mp.replay(rec, config=cfg, threshold=h, first_only=True) or [None])[0] for _, rec in recs[c]]
            delays = [None if f is None else f - PRE for f in firsts]
            hits = [d is not None and 0 <= d <= lim for d in delays]
            row[c] = {"runs": len(hits), "detected_within": int(sum(hits)), "within_frames": lim,
                      "early": sum(d is not None and d < 0 for d in delays), "delays": delays,
                      "missed_sites": sorted({s for (s, _), hit in zip(recs[c], hits) if not hit})}
        out["rows"][v] = row
        log(f"{v:24s} h {h:5.2f} false alarms {row['default']['false_alarms']} / {row['noisy']['false_alarms']}  "
            + "  ".join(f"{c} {row[c]['detected_within']}/{row[c]['runs']}" + (f" (early {row[c]['early']})"
                                                                              if row[c]['early'] else "")
                        for c in cells), flush=True)
    return out


def _pairnoise(null_seeds: list[int], n_base: int, n_null: int, steps: tuple, folders: tuple, log) -> dict:
    """The noise model's 3D-box part weighted per matched pair (``MonitorConfig.pair_noise``) against the
    independent per-edge model (the default): the same streams and step segments recorded with each
    (``folders`` = (the default's recordings, as ``--part iterate``; the per-pair model's), made when
    absent: the per-pair model changes every frame's rows), replayed with the default change test
    (``monitor_persistence.replay``, the guard included, the same threshold): false alarms on the long
    null streams (both noises) with the drift-free decisions' largest statistic (median, 99th
    percentile: the null's spread against the threshold), runs detected within the cell's target per
    cell with their delays."""
    import monitor_persistence as mp
    from xcalib.monitor import MonitorConfig

    step_seeds, runs, cells = steps
    within = {"r": {0.25: 50, 0.5: 20}, "t": {0.1: 50, 0.2: 20}}
    cfg = MonitorConfig(latch=False)
    out: dict = {"rows": {}, "null_seeds": null_seeds, "step_seeds": step_seeds, "runs_per_site": runs,
                 "cells": list(cells), "threshold": cfg.threshold,
                 "note": "replayed from recordings (the replay raises the monitor's alarms, guard included); the "
                         "per-pair rows recorded with MonitorConfig(pair_noise=True); the synthetic calibration carries "
                         "no fitted noise model (the default NoiseModel)"}
    for (v, settings), folder in zip((("independent (default)", None), ("per pair (pair_noise)", {"pair_noise": True})),
                                     folders):
        folder.mkdir(parents=True, exist_ok=True)
        jobs = [(folder, "null", name, s, n_base, n_null, settings) for name, _ in GUARD_NOISES for s in null_seeds]
        for done in [*_pmap(_guard_record, jobs), *_pmap(_cell_record, [(folder, s, runs, cells, settings)
                                                                        for s in step_seeds])]:
            log(f"  recorded {done}", flush=True)
        nulls = {(name, s): mp.load_recording(folder / f"null_{name}_{s}.npz") for name, _ in GUARD_NOISES
                 for s in null_seeds}
        row: dict = {}
        for name, _ in GUARD_NOISES:
            row[name] = _false_alarms(nulls, null_seeds, name, lambda rec: mp.replay(rec, config=cfg))
            stat = []
            for s in null_seeds:
                tr: list = []
                mp.replay(nulls[(name, s)], config=cfg, trace=tr)
                stat += [t[1] for t in tr]
            row[name]["decision_statistic_median_p99"] = [float(np.median(stat)), float(np.percentile(stat, 99))]
        for c in cells:
            lim = within[c[0]][float(c.split("_")[1])]
            recs = [(s, mp.load_recording(folder / f"step_{c.split('_')[0]}_{float(c.split('_')[1]):g}_{s}_{r}.npz"))
                    for s in step_seeds for r in range(runs)]
            firsts = [(mp.replay(rec, config=cfg, first_only=True) or [None])[0] for _, rec in recs]
            delays = [None if f is None else f - PRE for f in firsts]
            hits = [d is not None and 0 <= d <= lim for d in delays]
            row[c] = {"runs": len(hits), "detected_within": int(sum(hits)), "within_frames": lim,
                      "early": sum(d is not None and d < 0 for d in delays), "delays": delays,
                      "missed_sites": sorted({s for (s, _), hit in zip(recs, hits) if not hit})}
        out["rows"][v] = row
        log(f"{v:24s} false alarms {row['default']['false_alarms']} / {row['noisy']['false_alarms']}  null statistic "
            f"median / p99 {row['default']['decision_statistic_median_p99'][0]:.1f} / "
            f"{row['default']['decision_statistic_median_p99'][1]:.1f}  "
            + "  ".join(f"{c} {row[c]['detected_within']}/{row[c]['runs']}" for c in cells), flush=True)
    return out


def _spread(null_seeds: list[int], n_base: int, n_null: int, steps: tuple, folder: Path, quantiles: tuple,
            log) -> dict:
    """The change test's covariance at the objects' own spread of the difference
    (``MonitorConfig.difference_quantile``, each of ``quantiles``) against the default (the stated
    covariances), replayed (``monitor_persistence.replay``, the guard included, the same threshold) on the
    recordings of ``--part iterate`` (made when absent; the setting does not change the frames' rows):
    false alarms on the long null streams (both noises) with the drift-free decisions' largest statistic
    (median, 99th percentile), runs detected within the cell's target per cell with their delays."""
    import monitor_persistence as mp
    from xcalib.monitor import MonitorConfig

    step_seeds, runs, cells = steps
    within, nulls, recs = _iterate_recordings(null_seeds, n_base, n_null, steps, folder, log)
    variants = [("stated (default)", MonitorConfig(latch=False))]
    variants += [(f"difference_quantile={q:g}", MonitorConfig(latch=False, difference_quantile=q)) for q in quantiles]
    out: dict = {"rows": {}, "null_seeds": null_seeds, "step_seeds": step_seeds, "runs_per_site": runs,
                 "cells": list(cells), "threshold": variants[0][1].threshold,
                 "note": "replayed from recordings (the replay raises the monitor's alarms, guard included); the "
                         "null streams are --null-base frames looped with jitter, so an episode can recur"}
    for v, cfg in variants:
        row: dict = {}
        for name, _ in GUARD_NOISES:
            stat: list = []

            def alarms(rec, stat=stat, cfg=cfg):
                tr: list = []
                got = mp.replay(rec, config=cfg, trace=tr)
                stat += [t[1] for t in tr]
                return got

            row[name] = _false_alarms(nulls, null_seeds, name, alarms)
            row[name]["decision_statistic_median_p99"] = [float(np.median(stat)), float(np.percentile(stat, 99))]
        for c in cells:
            lim = within[c[0]][float(c.split("_")[1])]
            firsts = [(mp.replay(rec, config=cfg, first_only=True) or [None])[0] for _, rec in recs[c]]
            delays = [None if f is None else f - PRE for f in firsts]
            hits = [d is not None and 0 <= d <= lim for d in delays]
            row[c] = {"runs": len(hits), "detected_within": int(sum(hits)), "within_frames": lim,
                      "early": sum(d is not None and d < 0 for d in delays), "delays": delays,
                      "missed_sites": sorted({s for (s, _), hit in zip(recs[c], hits) if not hit})}
        row["within_total"] = int(sum(row[c]["detected_within"] for c in cells))
        out["rows"][v] = row
        log(f"{v:26s} false alarms {row['default']['false_alarms']} / {row['noisy']['false_alarms']}  null statistic "
            f"median / p99 {row['default']['decision_statistic_median_p99'][0]:.1f} / "
            f"{row['default']['decision_statistic_median_p99'][1]:.1f}  "
            + "  ".join(f"{c} {row[c]['detected_within']}/{row[c]['runs']}" for c in cells)
            + f"  within {row['within_total']}", flush=True)
    return out


#: ``--part scan``: thresholds of the scan read off the null streams (its false alarms there equal the
#: fixed windows' 1 / 0 at 29.0 and 0 / 0 at 30.5: session 13's sweep, docs/monitor.md "A change-point scan")
SCAN_THRESHOLDS = (29.0, 30.5)


def _verdicts(prev: dict, log) -> dict:
    """Each z step cell the benchmark has run at each site (``bound_s8`` -> ``monitor_steps``, and
    this session's ``relin_s9`` steps where present: the later run wins) against what the boxes
    allow there (``bound_verdict``): detected / possible / impossible, with the monitor's rate and
    the bound's powers. No monitor run: reads ``monitor.json``."""
    bound = prev.get("bound_s8") or {}
    rows: dict = {}
    for site, b in bound.items():
        if not site.startswith("site_"):
            continue
        for m in b.get("monitor_steps", []):
            key = f"tz_{m['size']:g}_within_{m['within']}"
            rows[f"{site}_{key}"] = {**bound_verdict(b, m["detected_within"], key, m["runs"]), "source": "bound_s8"}
    for name, c in ((prev.get("relin_s9") or {}).get("steps") or {}).items():
        if "bound" in c:
            rows[name] = {**c["bound"], "source": "relin_s9"}
    for name, v in sorted(rows.items(), key=lambda kv: (kv[0].split("_tz")[1], int(kv[0].split("_")[1]))):
        log(f"{name:28s} monitor {100 * v['monitor']:4.0f} % of {v['runs']}  bound: 6-dof time known "
            f"{_f(v['bound_6dof_time_known'], 2)}, oracle {_f(v['bound_oracle'], 2)}, fixed windows time unknown "
            f"{_f(v['bound_fixed_windows_time_unknown'], 2)}  -> {v['verdict']}")
    counts: dict = {}
    for name, v in rows.items():
        cell = "tz" + name.split("_tz")[1]
        counts.setdefault(cell, {"detected": 0, "possible": 0, "impossible": 0, "unknown": 0})[v["verdict"]] += 1
    for cell, c in counts.items():
        log(f"{cell}: " + ", ".join(f"{k} {n}" for k, n in c.items() if n) + " (sites)")
    return {"cells": rows, "counts": counts,
            "rule": "impossible: an efficient 6-dof test knowing the change time stays below 95 % power at the "
                    "false-alarm rate (the generator's boxes, optimistic); detected: the monitor reached 95 % of its "
                    "runs; possible: neither"}


def _relin_a9(n_null: int, n_step: int, band: float, factor: float, log) -> dict:
    """CPU per frame of the re-linearised window test at A9 density (``_a9``'s looped frames, one
    thread, the same run): a drift-free stream and a 10 cm z step at the middle of ``n_step``
    frames, without the test, recording it (every window in the band re-linearised, never
    alarming) and with it at ``factor`` times the threshold; alarms and decisions of each arm."""
    from xcalib.calib.api import calibrate
    from xcalib.io.sources import open_source

    seq = open_source(A9)
    raw = [seq[i] for i in range(len(seq))]
    cal = calibrate(raw, None)
    if not cal.success:
        return {"calibration": cal.message}
    out: dict = {"band": band, "factor": factor}
    arms = (("off", {}), ("recording", {"relinearise_band": band, "relinearise_factor": RECORD_ONLY}),
            (f"x{factor:g}", {"relinearise_band": band, "relinearise_factor": factor}))
    for case, n, change in (("null", n_null, None), ("tz_0.1", n_step, _change("translation", 0.10, 2))):
        for arm, cfg in arms:
            CONFIG.clear()
            CONFIG.update(cfg)
            q = _run(cal, _replay(raw, n, 1 if change is None else 2), k0=None if change is None else n // 2,
                     change=change, latch=change is not None)
            row = {"frames": q["frames"], "cpu_ms_per_frame": q["cpu_ms"], "alarms": q["alarms"],
                   "first_after_change": None if q["first"] is None or change is None else q["first"] - n // 2,
                   "relinearised_tests": len(q["relin"]), "states": q["states"]}
            out[f"{case}_{arm}"] = row
            log(f"A9 {case} {arm}: {row['cpu_ms_per_frame']:.2f} ms/frame, {row['relinearised_tests']} re-linearised "
                f"tests, alarms {row['alarms']}, first after the change {row['first_after_change']}, "
                f"states {row['states']}", flush=True)
    CONFIG.clear()
    return out


def _synthetic(result: dict, seeds: list[int], n_null: int, runs: int, log, nulls: bool = True) -> None:
    clean = {s: _synth_stream(s, n_null) for s in seeds}
    if not nulls:
        log("\n== synthetic steps (change at frame 250 of 350)")
        result["steps"] = _steps(clean, runs, log)
        return
    log(f"== synthetic null streams ({n_null} frames per site, sites {seeds})")
    noisy = {s: _synth_stream(s, n_null, box_noise_px=4.0, miss_rate_2d=0.1) for s in seeds}
    sparse = {s: _synth_stream(s, min(n_null, 1500), n_objects=(2, 5)) for s in seeds[:2]}
    result["null"] = [_null("default noise", clean, log), _null("4 px box noise, 10 % missed", noisy, log),
                      _null("sparse traffic (2-5 objects)", sparse, log)]
    log("\n== synthetic steps (change at frame 250 of 350)")
    result["steps"] = _steps(clean, runs, log)
    log("\n== synthetic ramps")
    result["ramps"] = _ramps(clean, max(2, runs // 3), log)


if __name__ == "__main__":
    main()
