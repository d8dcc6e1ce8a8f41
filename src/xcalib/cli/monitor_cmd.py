"""``xcalib monitor``: watch a calibrated camera's detections and say when it has moved."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from ..errors import FormatError

_HELP = "\n\n".join(" ".join(p.split("\n")) for p in """Watch a stream of frames against a calibration and say when the camera has moved, how far, and how sure.

SOURCE is any frame source (frame folder, HDF5 cache, KITTI, nuScenes, ROS 1 .bag / ROS 2 .db3 /
.mcap), read in time order. --calibration is a calibration .json/.npz or a site_calibration.json (every
calibrated camera is watched; --camera picks some). Over sliding windows of frames the pose change
relative to the calibration is estimated with its uncertainty, and each window is ok, drift (with
the change per axis and since when) or unknown (too few objects, and why). The change-point test
keeps false alarms below --false-alarm-rate per frame; the change it can detect at the stream's
traffic is printed, and the axes along which a change of the target size (0.25 deg / 10 cm) is
not observable from that traffic (weak_axes: typically the view axis z).

Writes OUT/monitor.jsonl, OUT/summary.json, OUT/report.html (the change over
time) and OUT/monitor.mcap (diagnostic_msgs/DiagnosticArray on /diagnostics, the estimated pose
on /tf, for Foxglove). --recalibrate runs calibrate on the frames after a change point
(OUT/recalibration/<camera>.json). Exit code: 0 ok (no change the test can see), 3 drift (the camera
moved), 1 could not tell (unknown: a stream shorter than one window, --window frames, or objects too few or
too weak to rule a change out; the summary line says which), 2 a usage error.

A stream to try it on, made by the package (60 synthetic frames, boxes only), calibrated, then watched (exit 0, ok):

Example: xcalib synth --out stream --frames 60 --train 0 --val 0 --test 60 --seed 3 --set 'n_objects=[15,30]' --no-images --no-lidar

Example: xcalib calibrate stream/test.h5 --out runs/stream_calib

Example: xcalib monitor stream/test.h5 --calibration runs/stream_calib/calibration.json --out runs/watch

A9's 16-frame sample (../shared/data/a9_sample) is shorter than one window: there the answer is unknown (exit 1,
"no decision yet"); a recording of a few minutes decides.

Example: xcalib monitor frames/ --calibration site_calibration.json --json > decisions.jsonl""".split("\n\n"))


def register(app: typer.Typer) -> None:
    @app.command("monitor", help=_HELP)
    def monitor_command(
        source: Path = typer.Argument(..., metavar="SOURCE", help="Frame source (xcalib.io.sources), in time order."),
        calibration: Path = typer.Option(..., "--calibration", "-C",
                                         help="Calibration .json/.npz or site_calibration.json."),
        camera: list[str] = typer.Option(None, "--camera", "-c", help="Camera to watch (repeat; default: all "
                                                                      "calibrated cameras)."),
        frame_range: str = typer.Option(None, "--frames", help="Frames to use: 0:100, 8: (indices)."),
        out: Path = typer.Option(Path("monitor_report"), "--out", "-o", help="Output folder."),
        false_alarm_rate: float = typer.Option(1e-4, "--false-alarm-rate",
                                               help="Expected false alarms per frame (default 1 per 10,000)."),
        window: int = typer.Option(20, "--window", help="Frames in the shortest window."),
        stride: int = typer.Option(5, "--stride", help="Frames between decisions."),
        fps: float = typer.Option(10.0, "--fps", help="Frame rate where frames carry no time stamps."),
        recalibrate: bool = typer.Option(False, "--recalibrate", help="After a drift, calibrate on the frames "
                                                                       "after the change point."),
        recalibrate_frames: int = typer.Option(20, "--recalibrate-frames", help="Frames --recalibrate uses."),
        reference: Path = typer.Option(None, "--reference", help="A drift-free stretch of the same site (a frame "
                                       "source): calibrates the change test per axis before SOURCE is monitored."),
        tolerance: float = typer.Option(0.05, "--tolerance", help="Bags: largest LiDAR/image stamp difference (s)."),
        as_json: bool = typer.Option(False, "--json", help="Print one JSON line per window, then a summary line."),
        force: bool = typer.Option(False, "--force", help="Replace an existing output folder."),
    ) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        from ..io.files import atomic_dir, atomic_write
        from ..monitor import Monitor, MonitorConfig, load_calibration
        from ..monitor.core import REFERENCE_SAMPLES
        from ..monitor.output import MonitorLog, MonitorMcap, write_monitor_html

        if out.exists() and not force and (not out.is_dir() or any(out.iterdir())):
            raise FileExistsError(f"{out} already exists; pass --force to replace it")
        try:
            config = MonitorConfig(window=window, stride=stride, false_alarm_rate=false_alarm_rate, fps=fps,
                                   history=max(600, 2 * window * 4),
                                   reference_samples=REFERENCE_SAMPLES if reference is not None else 0)
        except ValueError as exc:
            raise typer.BadParameter(str(exc)) from None
        cals = load_calibration(calibration)
        if camera:
            missing = [c for c in camera if c not in cals]
            if missing:
                raise typer.BadParameter(f"{calibration} has no calibrated camera {', '.join(missing)}; "
                                         f"cameras: {', '.join(cals)}", param_hint="--camera")
            cals = {c: cals[c] for c in camera}
        views = _open_views(source, list(cals), frame_range, tolerance, single=len(cals) == 1)
        monitor = Monitor(cals, config)
        log = MonitorLog()
        console = Console(stderr=True)
        learned = _learn(monitor, _open_views(reference, list(cals), None, tolerance, single=len(cals) == 1),
                         console) if reference is not None else None
        n = min(len(v) for v in views.values())
        console.print(f"monitor: {n} frames, cameras {', '.join(views)}; false alarms <= {false_alarm_rate:g} per "
                      f"frame (chi-square threshold {config.threshold:.1f}, 6 dof, windows of "
                      f"{', '.join(str(w) for w in config.windows)} frames every {stride})")
        lines = []
        with atomic_dir(out, overwrite=force) as tmp:
            with MonitorMcap(tmp / "monitor.mcap", monitor) as mcap, \
                    Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                             console=console, disable=as_json, transient=True) as bar:
                task = bar.add_task("monitor", total=n)
                shown_detectable = False
                for i in range(n):
                    for cam, seq in views.items():
                        frame = seq[i]
                        if len(views) > 1 or not frame.camera_name:
                            frame.camera_name = cam
                        for st in monitor.update(frame, i):
                            log.add(st)
                            mcap.add(st)
                            line = json.dumps(st.to_dict())
                            lines.append(line)
                            if as_json:
                                typer.echo(line)
                            elif (st.state == "drift" and st.frame == monitor.cameras[st.camera].events[-1].detected_frame) \
                                    or (not shown_detectable and st.state == "ok"):
                                console.print(_human(st))  # a new change, and the first detectable change
                                shown_detectable = shown_detectable or st.state == "ok"
                    bar.update(task, completed=i + 1)
            atomic_write(tmp / "monitor.jsonl", [("\n".join(lines) + "\n").encode() if lines else b""])
            recal = _recalibrate(monitor, views, tmp, recalibrate_frames, console) if recalibrate else {}
            summary = monitor.summary()
            summary["source"], summary["calibration"] = str(source), str(calibration)
            summary["recalibration"] = recal
            summary["reference"] = None if learned is None else {"source": str(reference), "cameras": learned}
            atomic_write(tmp / "summary.json", [json.dumps(summary, indent=1).encode()])
            write_monitor_html(tmp / "report.html", monitor, log, title=f"xcalib monitor: {source}")
        if as_json:
            typer.echo(json.dumps({"summary": summary}))
        else:
            for name, cs in summary["cameras"].items():
                typer.echo(f"{name}: {cs['state']}: {cs['message']}")
                dr, dt = cs["detectable_rotation_deg"], cs["detectable_translation_m"]
                if dr is not None:
                    typer.echo(f"  detectable change (95 % power, last window): rotation x/y/z "
                               f"{_fmt3(dr)} deg, translation x/y/z {_fmt3(dt, 100)} cm")
                pw = cs.get("power")
                if pw is not None:
                    seen = [a for a, v in pw["seen_at_target"].items() if v]
                    blind = [a for a, v in pw["seen_at_target"].items() if not v]
                    typer.echo(f"  steps seen within {pw['within_frames']} frames ({100 * pw['power']:.0f} % power, median over "
                               f"{pw['decisions']} decisions): rotation x/y/z {_fmt3(pw['rotation_deg_median'])} deg, "
                               f"translation x/y/z {_fmt3(pw['translation_m_median'], 100)} cm"
                               + (f"; at the target size only {', '.join(seen) or 'none'}" if blind else ""))
                if cs.get("weak_axes"):
                    tgt = cs["target_change"]
                    typer.echo(f"  not observable at {tgt['rotation_deg']:g} deg / {100 * tgt['translation_m']:g} cm "
                               f"from this traffic: {', '.join(cs['weak_axes'])} (r: rotation about, t: translation "
                               "along the camera axis)")
            typer.echo(f"state: {summary['state']} (exit code {summary['exit_code']}); wrote {out}/monitor.jsonl, "
                       f"summary.json, report.html, monitor.mcap")
        raise typer.Exit(monitor.exit_code)


def _fmt3(v, scale: float = 1.0) -> str:
    return "/".join("-" if x is None else f"{scale * x:.3g}" for x in v)


def _human(st) -> str:
    if st.state == "drift":
        return f"[red]frame {st.frame} ({st.time_s:.1f} s) {st.camera}: DRIFT[/red] {st.message}"
    return (f"frame {st.frame} {st.camera}: detectable change at this traffic (95 % power): rotation x/y/z "
            f"{_fmt3(st.detectable_rotation_deg)} deg, translation {_fmt3(st.detectable_translation_m, 100)} cm")


def _learn(monitor, views: dict, console) -> dict:
    """``Monitor.learn`` on a reference source's frames (every camera's, sweep by sweep)."""
    n = min(len(v) for v in views.values())

    def frames():
        for i in range(n):
            for cam, seq in views.items():
                frame = seq[i]
                if len(views) > 1 or not frame.camera_name:
                    frame.camera_name = cam
                yield frame

    with console.status(f"reference: {n} frames"):
        out = monitor.learn(frames())
    for cam, q in out.items():
        parts = [f"{k.split('_')[1]} frames: " + (", ".join(f"{a} {v:.2f}" for a, v in w["variance_factors"].items())
                                                   if w["variance_factors"] else f"too few ({w['samples']} samples)")
                 for k, w in q.items() if k.startswith("window_")]
        console.print(f"reference {cam}: {n} frames, {q['alarms']} change(s) inside it; the test's variance per "
                      f"axis x stated: {'; '.join(parts)}")
    return out


def _open_views(source: Path, cams: list[str], frame_range, tolerance: float, single: bool) -> dict:
    """camera -> its frames (lazy); one camera: the source's default camera unless it has that name."""
    from ..io.sources import find_source, open_source

    options = {"tolerance_s": tolerance} if find_source(source).name == "bag" else {}
    views = {}
    try:
        for c in cams:
            try:
                seq = open_source(source, camera=c, frames=frame_range, **options)
            except (KeyError, ValueError) as exc:
                if not single or isinstance(exc, FormatError):
                    raise
                seq = open_source(source, frames=frame_range, **options)  # a one-camera source named otherwise
            if len(seq) == 0:
                raise typer.BadParameter(f"{source}: no frames found", param_hint="SOURCE")
            views[c] = seq
    except ValueError as exc:
        if isinstance(exc, FormatError):
            raise
        raise typer.BadParameter(str(exc), param_hint="SOURCE / --camera / --frames") from None
    return views


def _recalibrate(monitor, views: dict, out: Path, n_frames: int, console) -> dict:
    """``calibrate`` on up to ``n_frames`` frames after each drifted camera's change point."""
    from ..calib.api import calibrate

    done = {}
    for cam, cm in monitor.cameras.items():
        if cm.drift is None:
            continue
        k = cm.drift.change_frame
        seq = views[cam]
        frames = [seq[i] for i in range(k, min(len(seq), k + n_frames))]
        if len(frames) < 2:
            done[cam] = {"success": False, "message": "fewer than 2 frames after the change point"}
            continue
        console.print(f"recalibrating {cam} on frames {k}..{k + len(frames) - 1}")
        res = calibrate(frames, cm.intr, prior=cm.estimated_pose().T)
        path = res.save(out / "recalibration" / f"{cam}.json")
        done[cam] = {"success": res.success, "message": res.message, "path": str(Path("recalibration") / path.name),
                     "frames": [k, k + len(frames)]}
        if res.success:
            from ..calib.pose import Pose

            r, t = Pose.parse(res).error(cm.pose0)
            done[cam].update(rotation_vs_calibration_deg=r, translation_vs_calibration_m=t)
        console.print(f"  {'calibrated' if res.success else 'refused'}: {res.message or res.summary().splitlines()[0]}")
    return done
