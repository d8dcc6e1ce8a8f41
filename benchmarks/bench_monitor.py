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
  detection and 100 frames after the change (|estimate - truth| / |truth|);
* ramps: 0.5 deg about x and 20 cm along x over 300 frames (30 s).

A9 (``../shared/data/a9_sample``, 16 real frames cycled: frame i of the stream is sample frame
i mod 16; calibration = ``calibrate`` on the 16 frames): the yaw-less boxes get their yaw from the
points once for the fast path (as a 3D detector with yaw delivers boxes): a 1,600-frame
drift-free stream; the frames as they are (yaw-less: ``prepare_frames`` fits yaw and point-hull
outlines every frame, as the calibration did): an 800-frame drift-free stream and the same
injected steps at frame 160 of 320 frames. CPU per frame (``time.process_time``, one thread) at A9
density, against ``calibrate`` on one window (20 frames) of the same frames in the same run; and
the cost with yaw-less boxes (yaw fitted from 43k points per frame by ``prepare_frames``).

Prints tables and writes ``benchmarks/results/monitor.json``.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_monitor.py [--full] [--sites N] [--runs N]

The committed results: ``--part synth --sites 2 --runs 8 --null-frames 800``, ``--part a9
--a9-frames 240`` and ``--part null --sites 1 --null-frames 5000`` (each part merges its keys
into the results file).
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
A9 = REPO.parent / "shared" / "data" / "a9_sample"
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


def _run(cal, frames, *, k0: int | None = None, change=None, ramp: int = 0, latch: bool = True) -> dict:
    """Monitor ``frames`` (a change from frame ``k0``: a step, or over ``ramp`` frames a ramp).
    Returns the first detection, the step estimates at detection and at the end, states, alarms, CPU."""
    from xcalib.monitor import Monitor, MonitorConfig
    from xcalib.monitor.inject import inject_change

    mon = Monitor(cal, MonitorConfig(latch=latch))
    cm = next(iter(mon.cameras.values()))
    states = {"ok": 0, "drift": 0, "unknown": 0}
    first, est_first, alarms, cpu = None, None, 0, 0.0
    for i, f in enumerate(frames):
        if change is not None and i >= k0:
            frac = 1.0 if not ramp else min(1.0, (i - k0 + 1) / ramp)
            f = inject_change(f, cal, change[0] * frac, change[1] * frac)
        t0 = time.process_time()
        sts = mon.update(f)
        cpu += time.process_time() - t0
        for st in sts:
            states[st.state] += 1
        if len(cm.events) > alarms:
            alarms = len(cm.events)
            if first is None:
                first = i
                est_first = cm.events[-1].step.copy()
    est_end = cm.events[0].step.copy() if cm.events and latch else None
    return {"first": first, "est_first": est_first, "est_end": est_end, "states": states, "alarms": alarms,
            "cpu_ms": 1e3 * cpu / max(len(frames), 1), "frames": len(frames),
            "model": cm.events[0].model if cm.events else None}


def _rel_err(est, kind: str, size: float, axis: int) -> float | None:
    if est is None:
        return None
    true = np.zeros(6)
    true[(0 if kind == "rotation" else 3) + axis] = size
    return float(np.linalg.norm(est - true) / size)


def _pct(v) -> float | None:
    v = [x for x in v if x is not None]
    return float(np.median(v)) if v else None


def _steps(streams: dict, runs: int, log) -> list[dict]:
    rows = []
    keys = list(streams)
    for kind, size, within in STEPS:
        for axis in range(3):
            res = []
            for r in range(runs):
                seed = keys[r % len(keys)]
                site, frames = streams[seed]
                k0 = PRE + ((r // len(keys)) * 137) % max(len(frames) - PRE - POST, 1)
                seg = frames[k0 - PRE:k0 + POST]
                res.append(_run(_synth_calibration(site), seg, k0=PRE, change=_change(kind, size, axis)))
            rows.append(_summarise(f"step {size:g} {'deg' if kind == 'rotation' else 'm'} {kind} {AXES[axis]}",
                                   res, kind, size, axis, within, PRE, log))
    return rows


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
           "est_err_at_end": _pct([_rel_err(q["est_end"], kind, size, axis) for q in res]),
           "axis_right": float(np.mean([q["est_end"] is not None and
                                        int(np.argmax(np.abs(q["est_end"]))) == (0 if kind == "rotation" else 3) + axis
                                        for q in res])),
           "cpu_ms_per_frame": float(np.mean([q["cpu_ms"] for q in res])), "size": size, "unit": unit}
    log(f"{name:34s} {row['detected_within'] * 100:5.0f} % <= {within:2d} fr  {row['detected_100'] * 100:4.0f} % <= 100  "
        f"delay {_f(row['delay_median'])} (max {_f(row['delay_max'])})  err@det {_f(row['est_err_at_detection'], 2)} "
        f"err@+100 {_f(row['est_err_at_end'], 2)}  axis {row['axis_right'] * 100:.0f} %  early {early}")
    return row


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


def _null(name: str, streams: dict, log) -> dict:
    frames_total, alarms, unknown, decisions, cpu = 0, 0, 0, 0, []
    for seed, (site, frames) in streams.items():
        q = _run(_synth_calibration(site), frames, latch=False)
        frames_total += q["frames"]
        alarms += q["alarms"]
        unknown += q["states"]["unknown"]
        decisions += sum(q["states"].values())
        cpu.append(q["cpu_ms"])
    upper = 3.0 / frames_total * 1e4 if alarms == 0 else None  # 95 % upper bound for zero events
    row = {"case": name, "frames": frames_total, "false_alarms": alarms,
           "false_alarms_per_10k": alarms / frames_total * 1e4, "upper95_per_10k_if_zero": upper,
           "unknown_share": unknown / max(decisions, 1), "cpu_ms_per_frame": float(np.mean(cpu))}
    log(f"{name:40s} {frames_total:6d} frames  {alarms} false alarms ({row['false_alarms_per_10k']:.2f} per 10k"
        f"{'' if upper is None else f'; 95 % bound {upper:.1f}'})  unknown {100 * row['unknown_share']:.0f} %  "
        f"cpu {row['cpu_ms_per_frame']:.2f} ms/frame")
    return row


def _a9(runs_cycle: int, n_step: int, log) -> dict:
    from xcalib.calib.api import calibrate
    from xcalib.calib.inputs import prepare_frames
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
    yawed = []
    for f in raw:  # the yaw once from the points, as a 3D detector with yaw would deliver the boxes
        cf = prepare_frames([f], cal.intrinsics, reestimate_yaw="auto", box_model="corners")[0][0]
        yawed.append(replace(f, bboxes_3d=cf.boxes3d.astype(np.float32), match_matrix=None, point_cloud=np.zeros((0, 3), np.float32)))

    def stream(n, src):
        return [replace(src[i % len(src)], lidar_time_s=0.1 * i, frame_key=str(i)) for i in range(n)]

    out = {"calibration_cpu_s": cal_cpu, "calibration_sigma": [*cal.rotation_std_deg, *cal.translation_std_m],
           "frames_2d_mean": float(np.mean([f.num_2d for f in raw])), "frames_3d_mean": float(np.mean([f.num_3d for f in raw]))}
    null = _run(cal, stream(runs_cycle, yawed), latch=False)
    null_raw = _run(cal, stream(runs_cycle // 5, raw), latch=False)
    out["null"] = {"frames": runs_cycle, "false_alarms": null["alarms"], "states": null["states"],
                   "cpu_ms_per_frame": null["cpu_ms"]}
    out["null_yawless"] = {"frames": runs_cycle // 5, "false_alarms": null_raw["alarms"], "states": null_raw["states"],
                           "cpu_ms_per_frame": null_raw["cpu_ms"]}
    log(f"A9 drift-free, {runs_cycle} frames (16 cycled), yawed boxes: {null['alarms']} alarms, states {null['states']}, "
        f"{null['cpu_ms']:.2f} ms CPU/frame")
    log(f"A9 drift-free, {runs_cycle // 5} frames, the sample's yaw-less boxes: {null_raw['alarms']} alarms, states "
        f"{null_raw['states']}, {null_raw['cpu_ms']:.1f} ms CPU/frame")
    rows = []
    for kind, size, within in STEPS:  # the frames as they are (yaw-less boxes: yaw and outlines from the points)
        for axis in range(3):
            q = _run(cal, stream(n_step, raw), k0=n_step // 2, change=_change(kind, size, axis))
            rows.append(_summarise(f"A9 step {size:g} {'deg' if kind == 'rotation' else 'm'} {kind} {AXES[axis]}",
                                   [q], kind, size, axis, within, n_step // 2, log))
    out["steps"] = rows
    win = yawed[:16] + yawed[:4]  # one 20-frame window
    t0 = time.process_time()
    calibrate(win, cal.intrinsics)
    cal_win = time.process_time() - t0
    yawless = null_raw
    out["cpu"] = {"monitor_ms_per_frame_yawed": null["cpu_ms"], "calibrate_window_20_frames_s": cal_win,
                  "calibrate_ms_per_frame_of_window": 1e3 * cal_win / 20,
                  "monitor_ms_per_frame_yawless_boxes": yawless["cpu_ms"]}
    log(f"A9 CPU (one thread): monitor {null['cpu_ms']:.2f} ms/frame (yawed boxes), "
        f"{yawless['cpu_ms']:.1f} ms/frame with yaw-less boxes (yaw + hulls from 43k points per frame); "
        f"calibrate on one 20-frame window {cal_win:.1f} s = {1e3 * cal_win / 20:.0f} ms/frame")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="30-min null streams (18,000 frames per site)")
    ap.add_argument("--sites", type=int, default=3)
    ap.add_argument("--runs", type=int, default=9, help="runs per step size and axis")
    ap.add_argument("--null-frames", type=int, default=1500)
    ap.add_argument("--skip-a9", action="store_true")
    ap.add_argument("--part", choices=("all", "synth", "a9", "null"), default="all",
                    help="run one part; its keys are merged into an existing results file")
    ap.add_argument("--a9-frames", type=int, default=320, help="A9 step streams (change at the middle)")
    args = ap.parse_args()
    n_null = 18000 if args.full else args.null_frames
    t_all = time.time()
    log = print
    seeds = [3, 5, 7, 11, 13, 17][:args.sites]
    result = {"machine": machine_info(), "config": "MonitorConfig() defaults"}
    out = REPO / "benchmarks" / "results" / "monitor.json"
    result[f"command_{args.part}"] = " ".join(sys.argv)
    from _provenance import provenance

    result[f"provenance_{args.part}"] = provenance()  # parts are merged: each keeps the run that made it
    if args.part == "null":  # longer drift-free streams only (the false-alarm rate)
        log(f"== long synthetic null streams ({n_null} frames per site, sites {seeds})")
        result["null_long"] = [_null("default noise", {s: _synth_stream(s, n_null) for s in seeds}, log),
                               _null("4 px box noise, 10 % missed",
                                     {s: _synth_stream(s, n_null, box_noise_px=4.0, miss_rate_2d=0.1) for s in seeds},
                                     log)]
    elif args.part != "a9":
        _synthetic(result, seeds, n_null, args.runs, log)
    if args.part in ("all", "a9") and not args.skip_a9 and A9.exists():
        log("\n== A9 (16 real frames cycled, injected drift)")
        result["a9"] = _a9(1600, args.a9_frames, log)
    result[f"wall_s_{args.part}"] = time.time() - t_all
    if args.part != "all" and out.exists():  # merged at write time: the other part may have finished meanwhile
        import json

        result = {**json.loads(out.read_text()), **result}
    write_result(out, result)


def _synthetic(result: dict, seeds: list[int], n_null: int, runs: int, log) -> None:
    log(f"== synthetic null streams ({n_null} frames per site, sites {seeds})")
    clean = {s: _synth_stream(s, n_null) for s in seeds}
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
