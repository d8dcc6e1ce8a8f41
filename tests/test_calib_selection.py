"""Frame selection for whole recordings (``xcalib.calib.selection``, issue 25 item 4)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_calib_support import INTR, sim_frames

from xcalib.calib.api import calibrate
from xcalib.calib.config import CalibConfig
from xcalib.calib.diagnostics import CalibDiagnostics
from xcalib.calib.selection import FrameBoxes, associate_objects, frame_boxes, scan_frames, select_frames


def _fb(centres3, centres2=None, ids=None, t=None, size=(1920, 1200)):
    c3 = np.asarray(centres3, dtype=float).reshape(-1, 3)
    c2 = np.asarray([[960.0, 600.0]] * max(len(c3), 1) if centres2 is None else centres2, dtype=float).reshape(-1, 2)
    return FrameBoxes(c3, None if ids is None else np.asarray(ids, np.int64), c2, np.full(len(c2), 60.0), size, t)


def _parked_recording(n: int, rng, miss: float = 0.2) -> list[FrameBoxes]:
    """A parked car at (20, 3, 0.8) in every frame (0.1 m box noise, missed in ``miss`` of them)
    and, from frame 100 to 160, a car driving past at 10 m/s."""
    out = []
    for k in range(n):
        c = []
        if rng.random() >= miss:
            c.append([20.0, 3.0, 0.8] + rng.normal(0, 0.1, 3))
        if 100 <= k < 160:
            c.append([40.0 - 1.0 * (k - 100), -4.0, 0.8] + rng.normal(0, 0.1, 3))
        out.append(_fb(c if c else np.zeros((0, 3)), t=0.1 * k))
    return out


def test_no_op_below_the_budget():
    rng = np.random.default_rng(0)
    boxes = _parked_recording(50, rng)
    sel = select_frames(boxes, 50)
    assert sel.all_used and np.array_equal(sel.indices, np.arange(50)) and sel.n_given == 50
    assert select_frames(boxes, None).all_used


def test_small_input_gives_the_same_calibration_as_without_selection():
    frames, T = sim_frames(seed=1, n_frames=6)
    a = calibrate(frames, INTR, CalibConfig(workers=1))
    b = calibrate(frames, INTR, CalibConfig(workers=1, max_frames=None))
    assert a.success == b.success and a.message == b.message
    assert np.array_equal(a.rotation, b.rotation) and np.array_equal(a.translation, b.translation)
    assert np.array_equal(a.rotation_std_deg, b.rotation_std_deg)
    s = a.diagnostics.selection
    assert (s.n_frames_given, s.n_frames_used, s.used_indices) == (6, 6, [])
    assert "6 of 6 used" in a.summary()


def test_a_static_object_seen_in_every_frame_counts_once():
    rng = np.random.default_rng(1)
    boxes = _parked_recording(500, rng)
    ids, n, how = associate_objects(boxes)
    assert how == "positions" and n == 2  # the parked car (with 20 % misses) and the passing one
    parked = np.concatenate([i[np.linalg.norm(b.centres_3d[:, :2] - [20.0, 3.0], axis=1) < 1] for i, b in zip(ids, boxes)])
    assert len(parked) > 350
    assert len(np.unique(parked)) == 1
    # with track ids the ids are used as they are (-1: no object)
    tracked = [dataclasses.replace(b, track_ids=np.where(b.centres_3d[:, 0] > 19, 7, -1)) for b in boxes]
    assert associate_objects(tracked)[1:] == (1, "tracks")
    # without timestamps too (frames assumed 0.1 s apart)
    assert associate_objects([dataclasses.replace(b, time_s=None) for b in boxes])[1] == 2


def test_chosen_frames_cover_distinct_objects_and_depths():
    rng = np.random.default_rng(2)
    boxes = [_fb([[20.0, 3.0, 0.8]], centres2=[[900.0, 700.0]], ids=[0], t=0.1 * k) for k in range(400)]
    rare = {37: 12.0, 151: 30.0, 222: 45.0, 390: 70.0}  # frames where another object shows, at that range
    for k, r in rare.items():
        c3 = np.array([[20.0, 3.0, 0.8], [r, -r * 0.3, 0.8]])
        c2 = np.array([[900.0, 700.0], [200.0 + 20 * r, 400.0]])
        boxes[k] = _fb(c3, centres2=c2, ids=[0, 100 + k], t=0.1 * k)
    boxes[300] = _fb(np.zeros((0, 3)), ids=np.zeros(0), t=30.0)  # no 3D boxes: nothing to use
    sel = select_frames(boxes, 10)
    assert sel.n_used == 10 and sel.n_objects == 5 and sel.n_objects_used == 5
    assert set(rare) <= set(sel.indices.tolist()) and 300 not in sel.indices
    assert np.all(np.diff(sel.indices) > 0)  # recording order
    # the rest spread over the recording, not bunched
    assert np.ptp(sel.indices) > 300
    depths = {float(np.linalg.norm(c[:2])) for i in sel.indices for c in boxes[i].centres_3d}
    assert len({int(d // 10) for d in depths}) >= 5


def test_moving_objects_are_tracked_by_position_and_clutter_is_no_object():
    rng = np.random.default_rng(3)
    boxes = []
    for k in range(200):
        c = [[-30.0 + 1.2 * k, 2.0, 0.8], [50.0 - 1.5 * k, -2.0, 0.8]]  # two cars passing, 12 and 15 m/s
        c = [x for x in c if rng.random() > 0.15]  # 15 % misses
        if k % 8 == 0:  # a random false box now and then (6 % of the boxes)
            c += [[rng.uniform(-60, 60), rng.uniform(-60, 60), 0.8]]
        boxes.append(_fb(np.asarray(c, dtype=float).reshape(-1, 3) + rng.normal(0, 0.1, (len(c), 3)), t=0.1 * k))
    ids, n, _ = associate_objects(boxes)
    assert n == 2
    assert sum(int(np.sum(i < 0)) for i in ids) >= 24  # the false boxes (25) belong to no object
    # frames far apart in time (no tracks): every box is an object of its own, none is clutter
    sparse = [_fb([[10.0 * k, 0.0, 0.8], [-5.0, 10.0 * k, 0.8]], t=1.0 * k) for k in range(20)]
    assert associate_objects(sparse)[1] == 40


def test_frame_boxes_reads_frames_and_tuples_and_names_bad_input():
    frames, _ = sim_frames(seed=3, n_frames=2)
    fb = frame_boxes(frames[0], 0)
    assert fb.centres_3d.shape == (len(frames[0].bboxes_3d), 3) and len(fb.centres_2d) == len(frames[0].bboxes_2d)
    f = frames[0]
    t = frame_boxes((f.image, f.point_cloud, f.bboxes_2d, f.bboxes_3d), 1)
    assert t.track_ids is None and np.allclose(t.centres_3d, fb.centres_3d)
    with pytest.raises(ValueError, match=r"frames\[4\].bboxes_3d"):
        frame_boxes((f.image, f.point_cloud, f.bboxes_2d, np.zeros((3, 5))), 4)
    bad = np.asarray(f.bboxes_3d, dtype=float).copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match=r"frames\[2\].bboxes_3d: NaN"):
        frame_boxes((f.image, f.point_cloud, f.bboxes_2d, bad), 2)
    with pytest.raises(TypeError, match=r"frames\[3\]"):
        frame_boxes("not a frame", 3)


class _Lazy:
    """A recording read one frame at a time (counts the reads)."""

    def __init__(self, frames):
        self.frames, self.reads = frames, 0

    def __len__(self):
        return len(self.frames)

    def __getitem__(self, i):
        self.reads += 1
        return self.frames[i]


def test_recording_calibrates_from_the_chosen_frames_and_says_so(tmp_path):
    from xcalib.data.synth import generate_frames, sample_site

    site = sample_site(0, preset="roadside")
    frames = generate_frames(site, 300, seed=0, render_images=False, lidar=False, miss_rate_2d=0.1,
                             false_positive_rate_2d=0.05, box_noise_px=1.0, center_noise_m=0.0,
                             size_noise_frac=0.0, yaw_noise_deg=0.0)
    lazy = _Lazy(frames)
    stages = []
    res = calibrate(lazy, site.intrinsics, CalibConfig(max_frames=24, workers=1),
                    progress=lambda s, d, t: stages.append((s, d, t)))
    assert res.success, res.message
    rot, trans = res.pose_error(site.T_cam_lidar)
    assert rot < 0.1 and trans < 0.1
    s = res.diagnostics.selection
    assert (s.n_frames_given, s.n_frames_used, s.object_identity) == (300, 24, "tracks")
    assert s.n_objects > 24 and s.n_objects_used == s.n_objects  # every object of the recording is used
    assert len(s.used_indices) == 24 and lazy.reads == 300 + 24  # scanned once, the chosen read again
    assert ("frames", 300, 300) in stages  # the progress bar over the frames
    # pairs line up with the given frames; frames not used have none
    assert len(res.pairs) == 300 and sum(len(res.pairs[i]) for i in s.used_indices) == res.n_pairs
    assert "24 of 300 used" in res.summary() and f"{s.n_objects} of {s.n_objects} distinct objects" in res.summary()
    d = CalibDiagnostics.from_dict(res.diagnostics.to_dict())
    assert d.selection == s
    # the report's frame table and overlays are of the used frames
    from xcalib.calib.report import write_report

    paths = write_report(res, frames, tmp_path, max_overlays=2, bringup_overlays=False)
    text = paths.summary.read_text()
    assert text.count("24 of 300 used") == 1  # the summary's "frames        = ..." line, once
    used_keys = {frames[i].frame_key for i in s.used_indices}
    rows = [ln.split()[0] for ln in text.splitlines() if ln.strip() and ln.split()[0] in {f.frame_key for f in frames}]
    assert set(rows) == used_keys and len(rows) == 24
    assert {p.stem for p in paths.overlays} <= used_keys and len(paths.overlays) == 2


def test_config_max_frames_is_checked():
    assert CalibConfig().max_frames == 200 and CalibConfig(max_frames=np.int64(40)).max_frames == 40
    for bad in (0, 1, 2.5, True, "many"):
        with pytest.raises(ValueError, match="max_frames"):
            CalibConfig(max_frames=bad)
    assert CalibConfig.from_dict({**CalibConfig().to_dict(), "max_frames": None}).max_frames is None


def test_with_a_time_offset_each_chosen_frame_comes_with_its_successor():
    from xcalib.calib.api import _selected_frames

    frames, _ = sim_frames(seed=4, n_frames=60, n_objects=(3, 6))
    for k, f in enumerate(frames):
        f.lidar_time_s, f.track_ids_3d = 0.1 * k, np.arange(len(f.bboxes_3d)) + 10 * k
    used, sel = _selected_frames(frames, INTR, CalibConfig(max_frames=20, time_offset="auto"), None)
    idx = sel.indices
    assert len(used) == len(idx) <= 20 and sel.max_frames == 20
    assert all(i + 1 in idx or i - 1 in idx for i in idx)  # pairs of consecutive frames
    used, sel = _selected_frames(frames, INTR, CalibConfig(max_frames=20), None)
    assert sel.n_used == 20


def test_a_mix_of_cameras_is_refused_with_selection_as_without():
    frames, _ = sim_frames(seed=5, n_frames=40, n_objects=(3, 6))
    for k, f in enumerate(frames):
        f.camera_name = "front" if k != 33 else "rear"  # one frame of another camera
    res = calibrate(frames, INTR, CalibConfig(max_frames=8, workers=1))
    assert not res.success and res.diagnostics.refusal == "mixed_cameras"
    assert 33 in res.diagnostics.selection.used_indices


@pytest.mark.parametrize("value", ["1", "-3"])
def test_cli_max_frames_rejects_bad_values(tmp_path, capsys, value):
    from xcalib.cli import main

    rc = main(["calibrate", str(tmp_path / "none"), "--out", str(tmp_path / "c"), "--max-frames", value])
    assert rc == 2 and not (tmp_path / "c").exists()
    out = capsys.readouterr()
    assert "max_frames" in out.err + out.out
