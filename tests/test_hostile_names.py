"""Names from a recording (cameras, topics, frame ids) are data, never code or paths: every writer
of a site calibration is fed names with ``/``, ``..``, newlines, quotes, ``$()`` and unicode
controls; the shell script runs no injected command, nothing is written outside the output folder,
and the URDF / tf / review files stay valid. Outputs are claimed before computing (issue 31)."""

from __future__ import annotations

import dataclasses
import os
import shlex
import signal
import subprocess
import sys
import textwrap
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from xcalib.calib.result import CalibrationResult
from xcalib.data.synth import generate_frames, sample_site
from xcalib.formats.ros import printable, ros_name
from xcalib.geometry.camera import CameraIntrinsics
from xcalib.io._files import OutputBusyError, atomic_dir, claim_output
from xcalib.site import SiteCalibration
from xcalib.site.calibration import CameraCalibration, camera_folders
from xcalib.site.ros import write_site_ros
from xcalib.viz.site_report import write_site_report

MARK = "XCALIB_PWNED"
HOSTILE = [
    f"cam\ntouch {MARK}_nl\n#",                 # a newline ends a comment line
    f"/tmp/{MARK}_abs/image",                  # an absolute path (an image topic)
    f"../../{MARK}_up",                         # climbs out of the output folder
    f"a'; touch {MARK}_q; '",                  # quotes
    f"$(touch {MARK}_sub)`touch {MARK}_bt`",   # command substitution
    "front\u202eevil\u0000\r",                  # bidi override, NUL, carriage return
    "cam/front",                                 # two names that map to one token ...
    "cam_front",                                 # ... must not share a folder
]


def _result(success: bool, name: str) -> CalibrationResult:
    if not success:
        return CalibrationResult(success=False, message=f"refused: {name}\nrm -rf / # {name}", camera_name=name)
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]) @ np.array(
        [[0.99, -0.141067, 0.0], [0.141067, 0.99, 0.0], [0.0, 0.0, 1.0]])
    return CalibrationResult(success=True, intrinsics=CameraIntrinsics(800.0, 800.0, 320.0, 240.0, None, 640, 480),
                             rotation=R, translation=np.array([0.1, -0.2, 0.3]), camera_name=name,
                             image_size=(640, 480))


def _site(lidar_frame: str = f"velodyne\n touch {MARK}_lidar") -> SiteCalibration:
    cams = tuple(CameraCalibration(n, _result(i % 2 == 0, n), 1) for i, n in enumerate(HOSTILE))
    return SiteCalibration(cams, lidar_frame=lidar_frame, source="evil.bag")


def _no_marks(root: Path) -> None:
    # what an injected ``touch`` or a path escape would create (safe file names may hold the text)
    found = [p for p in root.rglob(f"{MARK}*")] + [p for p in Path("/tmp").glob(f"{MARK}*")]
    assert not found, f"an injected name created {found}"


def test_ros_name_and_printable_neutralise_names():
    assert ros_name("velodyne") == "velodyne" and ros_name("/ns/velodyne") == "ns/velodyne"
    for n in HOSTILE:
        r = ros_name(n)
        assert r and all(c.isascii() and (c.isalnum() or c in "_./-") for c in r) and not r.startswith(("/", "-"))
        p = printable(n)
        assert "\n" not in p and "\r" not in p and "\u202e" not in p and "\x00" not in p
    folders = camera_folders(HOSTILE)
    assert len(set(v.lower() for v in folders.values())) == len(HOSTILE)
    assert all("/" not in v and not v.startswith(".") and v not in ("", ".", "..") for v in folders.values())


def test_static_transforms_script_runs_no_injected_command(tmp_path):
    out = tmp_path / "cal" / "ros"
    write_site_ros(_site(), out)
    script = out / "static_transforms.sh"
    # a stand-in ros2 / rosrun that records its arguments: the script must hand them over as data
    bindir = tmp_path / "bin"
    bindir.mkdir()
    log = tmp_path / "calls.txt"
    for tool in ("ros2", "rosrun"):
        # one write per call: the script starts its publishers in the background, so two appends per
        # call (arguments, then the newline) interleave between concurrent stand-ins
        (bindir / tool).write_text(f'#!/bin/sh\nline=$(printf "%s|" "$@")\nprintf "%s\\n" "$line" >> '
                                   f'{shlex.quote(str(log))}\n')
        (bindir / tool).chmod(0o755)
    env = {"PATH": f"{bindir}:/usr/bin:/bin"}
    for ros in ("1", "2"):  # the ROS 1 (rosrun) and ROS 2 (ros2 run) branches
        run = subprocess.run(["sh", str(script), ros], cwd=tmp_path, env=env, capture_output=True, text=True,
                             timeout=60)
        assert run.returncode == 0, run.stderr
    _no_marks(tmp_path)
    calls = [line for line in log.read_text().splitlines() if line]
    n_ok = sum(1 for i in range(len(HOSTILE)) if i % 2 == 0)
    assert len(calls) == 2 * n_ok  # one publisher per calibrated camera, per ROS generation
    for line in calls:
        args = line.split("|")
        names = [args[i + 1] for i, a in enumerate(args[:-1]) if a in ("--frame-id", "--child-frame-id")]
        names += [a for a in args[-3:-1] if not a.startswith("-")] if args[0] == "tf2_ros" else []
        assert names and all(n == ros_name(n) and "\n" not in n for n in names), line
    comments = [line for line in script.read_text().splitlines() if line.startswith("#")]
    assert all(line.isprintable() for line in comments)


def test_every_writer_stays_inside_out_and_valid(tmp_path):
    box = tmp_path / "box"
    out = box / "out"
    site = _site()
    frame = generate_frames(sample_site(0, "roadside"), 1, seed=0)[0]
    frame = dataclasses.replace(frame, image=frame.image[:480, :640],  # the camera the results describe
                                intrinsics=_result(True, "camera").intrinsics)
    frames = {c.camera: [frame] for c in site.cameras}
    with atomic_dir(out) as tmp:
        paths = write_site_report(tmp, site, frames, max_overlays=1)
    _no_marks(tmp_path)
    assert sorted(p.name for p in box.iterdir()) == ["out"]  # nothing beside it, no temp left
    for p in out.rglob("*"):
        assert out in p.resolve().parents, p
    folders = camera_folders([c.camera for c in site.cameras])
    assert all((out / f).is_dir() for f in folders.values())
    urdf = ET.parse(out / "ros" / "site.urdf").getroot()
    links = {e.get("name") for e in urdf.iter("link")}
    assert all(n == ros_name(n) for n in links) and ros_name(site.lidar_frame) in links
    tf = yaml.safe_load((out / "ros" / "tf_static.yaml").read_text())
    assert all(t["child_frame_id"] == ros_name(t["child_frame_id"]) for t in tf["transforms"])
    from mcap.reader import make_reader

    with open(out / "review.mcap", "rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert all(t.startswith("/") and ros_name(t[1:]) == t[1:] for t in topics), topics
    assert paths.relocated(tmp, out).site_json.is_file()


_HOLD = textwrap.dedent("""
    import sys, time
    from xcalib.io._files import claim_output
    with claim_output(sys.argv[1]):
        print("held", flush=True)
        time.sleep(120)
""")


def _holder(path: Path) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-c", _HOLD, str(path)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    return p


def test_claim_refuses_a_second_run_at_once_and_dies_with_its_holder(tmp_path):
    out = tmp_path / "out"
    holder = _holder(out)
    try:
        with pytest.raises(OutputBusyError, match=str(holder.pid)):
            with claim_output(out):
                pass
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with claim_output(out) as lock:  # a killed holder leaves nothing that blocks the next run
        assert lock.is_file()
    assert not lock.exists()


def test_calibrate_to_a_claimed_out_is_refused_before_computing(tmp_path, capsys):
    from xcalib.cli import main

    out = tmp_path / "run"
    holder = _holder(out)
    try:
        code = main(["calibrate", str(tmp_path / "missing_frames"), "--out", str(out)])
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert code == 1
    assert "being written by another run" in capsys.readouterr().err
    assert not out.exists()


def test_atomic_dir_never_swaps_away_a_folder_filled_meanwhile(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(FileExistsError, match="another process"):
        with atomic_dir(out) as tmp:
            (tmp / "mine.txt").write_text("second run")
            out.mkdir()
            (out / "theirs.txt").write_text("first run")
    assert sorted(p.name for p in out.iterdir()) == ["theirs.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # our temp is gone


def test_writers_sweep_temps_of_killed_writers(tmp_path):
    from xcalib.io.bags import write_bag
    from xcalib.viz.review import write_review_mcap

    dead = 2 ** 22 + 12345  # no such process
    stale = [tmp_path / f".review.mcap.{dead}.abc.tmp", tmp_path / f".x.mcap.{dead}.abc.tmp"]
    stale[0].write_bytes(b"junk")
    stale[1].mkdir()
    frame = generate_frames(sample_site(0, "roadside"), 1, seed=0, render_images=False)[0]
    write_bag(tmp_path / "x.mcap", [frame])
    site = SiteCalibration((CameraCalibration("camera", _result(True, "camera"), 1),))
    write_review_mcap(tmp_path / "review.mcap", site, {"camera": [frame]}, max_frames=1)
    assert not any(p.exists() for p in stale)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["review.mcap", "x.mcap"]


def test_bag_write_refuses_a_suffix_no_reader_recognises(tmp_path):
    from xcalib.io.bags import write_bag

    frame = generate_frames(sample_site(0, "roadside"), 1, seed=0, render_images=False)[0]
    with pytest.raises(ValueError, match=r"x\.mcap"):
        write_bag(tmp_path / "x.MCAP", [frame])
    assert not any(tmp_path.iterdir())


def test_second_bootstrap_to_one_site_is_refused_at_once(tmp_path, monkeypatch):
    from xcalib.engine.checkpoint import site_dirs
    from xcalib.oneshot.bootstrap import bootstrap

    monkeypatch.setenv("XCALIB_HOME", str(tmp_path / "home"))
    target = site_dirs("busy_site")[0]
    holder = _holder(target)
    seen = []

    def frames():  # records whether bootstrap started reading
        seen.append(1)
        yield from ()

    try:
        with pytest.raises(OutputBusyError, match="busy_site"):
            bootstrap(frames(), None, "busy_site")
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert not target.exists() and not seen  # nothing read, nothing installed


def test_oneshot_save_is_one_swap(tmp_path):
    """Weights, config and oneshot.json of a session land together (one folder swap)."""
    import json

    from xcalib.engine.matcher import Matcher
    from xcalib.oneshot.session import OneShotSession

    site = sample_site(0, "roadside")
    session = OneShotSession(Matcher.from_pretrained("fastmatch", site="synthetic"), site.intrinsics)
    (tmp_path / "w").mkdir()
    (tmp_path / "w" / "calibration.json").write_text("{}")  # another run's pose: must not stay beside these
    paths = session.save(tmp_path / "w")
    assert json.loads(paths["oneshot"].read_text())["format"] == "xcalib-oneshot-v1"
    names = sorted(p.name for p in (tmp_path / "w").iterdir())
    assert "calibration.json" not in names and "oneshot.json" in names and paths["weights"].name in names
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w"]
