"""Frames streamed in bounded memory (issue 31, item 5): each frame read once and slimmed to its
boxes and the points near them; the calibration of the slimmed frames is that of the whole ones;
an input over the memory limit is refused up front, naming it, the estimate and the limit."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _long_recording import LongRecording
from conftest import shared_path
from xcalib.errors import MemoryLimitError
from xcalib.site.stream import (ReportFrames, StreamConfig, frame_nbytes, keep_mask, parse_memory, slim_frame,
                                stream_views)

REPO = Path(__file__).resolve().parents[1]


class _Counting:
    """A source that counts the frames read."""

    def __init__(self, base):
        self.base, self.reads = base, 0
        self.intrinsics = base.intrinsics

    def __len__(self):
        return len(self.base)

    def __getitem__(self, i):
        self.reads += 1
        return self.base[i]


@pytest.mark.parametrize("yawless", [True, False])
def test_streamed_frames_calibrate_as_the_whole_ones(yawless):
    from xcalib.calib.api import calibrate

    rec = LongRecording(4, 20_000, seed=3, yawless=yawless)
    whole = [rec[i] for i in range(len(rec))]
    src = _Counting(rec)
    slim = stream_views({"cam": src}, StreamConfig())["cam"]
    assert src.reads == len(rec) + 3  # each frame once (+ the first, middle and last for the estimate)
    assert all(f.image.size == 0 and f.meta["image_size"] == (rec.intrinsics.width, rec.intrinsics.height)
               for f in slim)
    assert sum(frame_nbytes(f) for f in slim) < 0.1 * sum(frame_nbytes(f) for f in whole)
    a = calibrate(whole, rec.intrinsics)
    b = calibrate(list(slim), rec.intrinsics)
    assert (a.success, a.message, a.n_pairs) == (b.success, b.message, b.n_pairs)
    assert a.diagnostics.box_model == b.diagnostics.box_model
    if yawless:  # the yaw fit and the point hulls read the points: they ran on the slimmed clouds
        assert "points" in b.diagnostics.box_model
    T_a = a.extrinsics if a.success else np.asarray(a.diagnostics.refused_T)
    T_b = b.extrinsics if b.success else np.asarray(b.diagnostics.refused_T)
    np.testing.assert_allclose(T_b, T_a, atol=1e-9, rtol=0)


def test_keep_mask_is_the_points_of_its_cylinders():
    rng = np.random.default_rng(0)
    pts = rng.uniform([-40, -40, -3], [40, 40, 3], (200_000, 3)).astype(np.float32)
    regions = np.column_stack([rng.uniform(-30, 30, (25, 2)), rng.uniform(0.5, 5, 25), rng.uniform(-2, 0, 25),
                               rng.uniform(0, 2, 25)])
    regions[0, 2] = 500.0  # one huge cylinder: tested directly
    regions[0, 3:] = (2.5, 2.6)
    inside = np.zeros(len(pts), bool)
    for cx, cy, r, zl, zh in regions:
        inside |= ((pts[:, 0] - cx) ** 2 + (pts[:, 1] - cy) ** 2 <= r * r) & (pts[:, 2] >= zl) & (pts[:, 2] <= zh)
    keep = keep_mask(pts, regions)
    np.testing.assert_array_equal(keep, inside)


def test_slim_frame_keeps_one_point_of_a_cloud_far_from_every_box():
    rec = LongRecording(1, 5_000, seed=1)
    f = rec[0]
    far = f.point_cloud.copy()
    far[:, :2] += 1e4
    s = slim_frame(type(f)(**{**f.__dict__, "point_cloud": far}))
    assert s.point_cloud.shape == (1, 3)


def test_memory_limit_refused_up_front_naming_input_estimate_and_limit():
    src = _Counting(LongRecording(30, 200_000, seed=0))
    with pytest.raises(MemoryLimitError) as exc:
        stream_views({"front": src}, StreamConfig(max_memory_mb=20), source="long.mcap")
    msg = str(exc.value)
    assert src.reads == 3  # refused from the first, middle and last frame, before the rest is read
    assert msg.startswith("long.mcap: ") and "the limit is 20 MB" and "--max-memory" in msg
    assert "30 frame(s)" in msg and "up to 200000 points" in msg
    assert exc.value.estimate_bytes > exc.value.limit_bytes == 20 << 20


def test_memory_limit_while_reading_names_the_frame():
    class Growing(_Counting):  # the sampled frames have no 3D box: the estimate is low
        def __getitem__(self, i):
            f = super().__getitem__(i)
            return f if i not in (0, 20, 39) else type(f)(**{**f.__dict__, "bboxes_3d": f.bboxes_3d[:0], "meta": {}})

    from xcalib.site.stream import _first_estimate, estimate_memory

    src = Growing(LongRecording(40, 200_000, seed=0, image=False))
    need = estimate_memory([_first_estimate("cam", src, StreamConfig())])  # what the sampled frames promise
    with pytest.raises(MemoryLimitError, match=r"after \d+ of 40 frames the slimmed frames hold"):
        stream_views({"cam": src}, StreamConfig(max_memory_mb=need / 2 ** 20 + 1))


def test_report_frames_reread_the_drawn_frames_whole():
    rec = LongRecording(12, 20_000, seed=2)
    s = stream_views({"cam": rec})["cam"]
    rf = s.for_report(3)
    assert isinstance(rf, ReportFrames) and len(rf) == 12
    assert rf.whole == {0, 6, 11}  # the overlays, spread (the review file's frames by default too)
    assert s.for_report(3, [0, 3, 7, 11]).whole == {0, 3, 6, 7, 11}  # and the review file's given frames
    assert rf[6].point_cloud.shape == (20_000, 4) and rf[6].image.shape[0] == rec.intrinsics.height
    assert rf[5].point_cloud.shape[0] < 20_000 and rf[5].image.size == 0
    np.testing.assert_array_equal(rf[6].bboxes_3d, s[6].bboxes_3d)


def test_parse_memory():
    assert parse_memory("2G") == 2048 and parse_memory("1500M") == 1500 and parse_memory("0") == 0
    assert parse_memory("1.5GB") == 1536 and parse_memory("512MiB") == 512
    with pytest.raises(ValueError, match="not a memory size"):
        parse_memory("lots")


_RSS_CHILD = r"""
import json, resource, sys
sys.path.insert(0, "tests")
from _long_recording import LongRecording
from xcalib.site.stream import StreamConfig, frame_nbytes, stream_views
rec = LongRecording(30, 200_000, seed=0)
whole = sum(frame_nbytes(rec[i]) for i in range(2)) * len(rec) / 2  # every frame held whole
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
s = stream_views({"cam": rec}, StreamConfig())["cam"]
rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"whole": whole, "growth": rss1 - rss0, "held": s.held_bytes}))
"""


def test_streaming_peak_rss_is_far_below_all_frames():
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"), OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", _RSS_CHILD], cwd=REPO, env=env, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["whole"] > 250e6  # 30 frames of 200k points and a 1920x1200 image
    assert r["held"] < 0.05 * r["whole"]
    assert r["growth"] < 0.3 * r["whole"], r


def test_calibrate_cli_refuses_over_max_memory(tmp_path):
    from xcalib.cli import main

    a9 = shared_path("a9_sample")
    rc = main(["calibrate", str(a9), "--out", str(tmp_path / "o"), "--max-memory", "2M"])
    assert rc == 1 and not (tmp_path / "o" / "calibration.json").exists()


def test_calibrate_cli_rejects_a_bad_max_memory(tmp_path):
    from xcalib.cli import main

    rc = main(["calibrate", str(tmp_path), "--out", str(tmp_path / "o"), "--max-memory", "lots"])
    assert rc == 2
