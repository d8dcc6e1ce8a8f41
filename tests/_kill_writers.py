"""Writers killed with SIGKILL mid-write (issue 16), shared by tests/test_kill_writes.py and
benchmarks/bench_untrusted.py.

``python tests/_kill_writers.py KIND OUT`` rewrites output ``OUT`` forever, version 0, 1, 2, ...
(each version distinguishable), printing ``ready`` after the first. ``check(KIND, OUT)`` loads
what is there after the kill and says whether it is one whole version; ``leftovers(OUT)`` lists
temp files/folders beside it after the next writer's sweep.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

KINDS = ("save_pretrained", "synth_site", "calibrate_report", "export_ros", "export_opencalib", "cache")
HERE = Path(__file__).resolve().parent


def _result(v: int):
    from xcalib.calib.result import CalibrationResult
    from xcalib.geometry import CameraIntrinsics, euler_to_matrix

    return CalibrationResult(success=True, intrinsics=CameraIntrinsics(500.0 + v, 500.0 + v, 320, 240, None, 640, 480),
                             rotation=euler_to_matrix([-1.5, 0.02 * v, -1.6]), translation=[0.01 * v, -0.3, -0.2],
                             camera_name="cam", frame_keys=["0000"], pairs=[np.zeros((0, 2), np.int64)])


def _frames(v: int):
    from xcalib.types import Frame

    rng = np.random.default_rng(v)
    return [Frame(image=np.full((480, 640, 3), v % 255, np.uint8), point_cloud=rng.normal(size=(4000, 3)).astype(np.float32),
                  bboxes_2d=np.array([[10, 10, 30, 30]], np.float32), bboxes_3d=np.array([[1, 1, 0, 2, 2, 1]], np.float32),
                  camera_name="cam", frame_key=f"{k:04d}", extrinsics=np.eye(4)) for k in range(20)]


def write(kind: str, out: Path, v: int) -> None:
    """Write version ``v`` of output ``kind`` at ``out`` (replacing the previous one)."""
    if kind == "save_pretrained":
        import torch

        from xcalib.engine.matcher import Matcher
        from xcalib.models import create_model

        torch.manual_seed(v)
        Matcher(create_model("fastmatch", {"embed_dim": 16 + 8 * (v % 2)}), device="cpu").save_pretrained(
            out, overwrite=True)
    elif kind == "synth_site":
        from xcalib.data.synth import write_site

        write_site(out, 1, 0, 1, seed=v % 3, render_images=False, lidar=False, overwrite=True)
    elif kind == "calibrate_report":
        from xcalib.calib.report import write_report
        from xcalib.io._files import atomic_dir

        with atomic_dir(out, overwrite=True) as tmp:  # what `xcalib calibrate --out` does
            write_report(_result(v), _frames(v)[:1], tmp, max_overlays=0)
    elif kind == "export_ros":
        from xcalib.formats.export import export_calibration

        export_calibration(_result(v), "ros", out / "camera_info.yaml")
    elif kind == "export_opencalib":
        from xcalib.formats.export import export_calibration

        export_calibration(_result(v), "opencalib", out)
    elif kind == "cache":
        from xcalib.io.hdf5 import write_cache

        write_cache(out / "c.h5", _frames(v), image_format="png")
    else:
        raise ValueError(kind)


def check(kind: str, out: Path) -> tuple[bool, str]:
    """(whole, detail): the output at ``out`` is absent (never written) or one complete version."""
    try:
        if kind == "save_pretrained":
            from xcalib.engine.matcher import Matcher

            if not out.exists():
                return True, "absent"
            Matcher.from_pretrained("fastmatch", weights=out, device="cpu")
        elif kind == "synth_site":
            from xcalib.io.hdf5 import CacheReader

            if not out.exists():
                return True, "absent"
            info = json.loads((out / "site.json").read_text())
            for split in ("train", "test"):
                with CacheReader(out / f"{split}.h5", read_images=False) as r:
                    if not np.allclose(r[0].extrinsics, info["T_cam_lidar"]):
                        return False, f"{split}.h5 and site.json from different runs"
        elif kind == "calibrate_report":
            from xcalib.calib.result import CalibrationResult

            if not out.exists():
                return True, "absent"
            a, b = CalibrationResult.load(out / "calibration.json"), CalibrationResult.load(out / "calibration.npz")
            t = f"{a.translation[0]:+.3f}"
            if not np.allclose(a.extrinsics, b.extrinsics) or t not in (out / "summary.txt").read_text():
                return False, "calibration.json / .npz / summary.txt from different writes"
        elif kind == "export_ros":
            from xcalib.formats.export import read_calibration

            if not (out / "camera_info.yaml").exists():
                return True, "absent"
            r = read_calibration(out / "camera_info.yaml", "ros")
            v = round(r.intrinsics.fx - 500.0)
            if not np.allclose(r.translation[0], 0.01 * v, atol=1e-9):
                return False, "camera_info.yaml and its _tf.yaml from different writes"
        elif kind == "export_opencalib":
            from xcalib.formats.export import read_calibration

            if not any(out.glob("*-extrinsic.json")):
                return True, "absent"
            r = read_calibration(out, "opencalib")
            v = round(r.intrinsics.fx - 500.0)
            if not np.allclose(r.translation[0], 0.01 * v, atol=1e-9):
                return False, "extrinsic and intrinsic json from different writes"
        elif kind == "cache":
            from xcalib.io.hdf5 import CacheReader

            if not (out / "c.h5").exists():
                return True, "absent"
            with CacheReader(out / "c.h5") as r:
                [r[i] for i in range(len(r))]
    except Exception as exc:  # noqa: BLE001 - any failure to load is a half-written output
        return False, f"{type(exc).__name__}: {exc}"
    return True, "whole"


def leftovers(out: Path) -> list[str]:
    """Temp entries (``.<name>.<pid>.*.tmp|.old``) beside / inside the output after a sweep."""
    import re

    pat = re.compile(r"^\..+\.\d+\.[A-Za-z0-9_]+\.(tmp|old)$")
    places = [out.parent] + ([out] if out.is_dir() else [])
    return sorted(str(p / n) for p in places for n in os.listdir(p) if pat.match(n))


def sweep(out: Path) -> None:
    """What the next writer does first: remove the temps of writers that no longer run."""
    import re

    from xcalib.io._files import sweep_stale

    pat = re.compile(r"^\.(.+)\.\d+\.[A-Za-z0-9_]+\.(?:tmp|old)$")
    for d in {out.parent, out}:
        if d.is_dir():
            for name in os.listdir(d):
                m = pat.match(name)
                if m:
                    sweep_stale(d, m.group(1))


def kill_during_write(kind: str, out: Path, delay_s: float, timeout_s: float = 60.0) -> None:
    """Start a child rewriting ``out``; SIGKILL it ``delay_s`` after its first complete version."""
    env = dict(os.environ, PYTHONPATH=str(HERE.parent / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""),
               OMP_NUM_THREADS="1")
    child = subprocess.Popen([sys.executable, str(Path(__file__)), kind, str(out)], stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, env=env, text=True)
    try:
        t0 = time.monotonic()
        line = child.stdout.readline()
        if "ready" not in line:
            raise RuntimeError(f"writer {kind} did not start (exit {child.poll()})")
        time.sleep(delay_s)
        if time.monotonic() - t0 > timeout_s:
            raise RuntimeError("writer too slow")
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()


if __name__ == "__main__":
    kind, out = sys.argv[1], Path(sys.argv[2])
    if kind in ("export_ros", "export_opencalib", "cache"):
        out.mkdir(parents=True, exist_ok=True)
    v = 0
    while True:
        write(kind, out, v)
        if v == 0:
            print("ready", flush=True)
        v += 1
