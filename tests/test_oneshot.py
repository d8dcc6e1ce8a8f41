"""One-shot site adaptation: session calibration gate, pseudo-labels, loss, augmentation, adapt,
bad input, bit-exact save/reload, site lookup, ``xcalib bootstrap``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from _matching_frames import small_site, states_equal, tiny_matcher
from xcalib.calib.result import CalibrationResult
from xcalib.data.synth import generate_frames
from xcalib.engine.matcher import Matcher
from xcalib.oneshot.augment import GeometricAugment, _iou, _rects
from xcalib.oneshot.loss import weighted_matching_loss
from xcalib.oneshot.session import ImageSizeChangedError, NotCalibratedError, OneShotSession


@pytest.fixture(scope="module")
def site():
    return small_site()


@pytest.fixture(scope="module")
def frames(site):
    return generate_frames(site, 8, seed=1, render_images=False)


_matcher = tiny_matcher


def _observe(session: OneShotSession, frames):
    return [session.observe_frame(f, validate="off") for f in frames]


def _gt_pose(site) -> CalibrationResult:
    T = site.T_cam_lidar
    return CalibrationResult(success=True, intrinsics=site.intrinsics, rotation=T[:3, :3], translation=T[:3, 3])


_states_equal = states_equal


def test_session_calibrates_from_detections_on_an_explicit_schedule(site, frames):
    s = _matcher().oneshot(site.intrinsics, min_frames=3, recalibrate_growth=1.5)
    reps = _observe(s, frames[:6])
    assert [r.calibration is not None for r in reps] == [False, False, True, False, True, False]  # at 3, then 5
    assert [r.next_calibration_at for r in reps[:3]] == [3, 3, 5]
    assert s.is_calibrated and reps[-1].calibrated
    rot, tr = s.calibration.pose_error(site.T_cam_lidar)
    assert rot < 1.0 and tr < 0.5
    assert reps[-1].n_pseudo_pairs >= 5 and reps[-1].buffer_frames == 6
    assert s.calibration.meta["buffer_frames"] >= 3 and np.isfinite(s.calibration.buffer_reproj_px)


def test_gate_accepts_only_a_pose_that_explains_the_buffer_better(site, frames, monkeypatch):
    import xcalib.calib.api as api

    s = _matcher().oneshot(site.intrinsics, min_frames=100)  # no automatic attempt
    _observe(s, frames[:4])
    gt = _gt_pose(site)
    bad = CalibrationResult(success=True, intrinsics=site.intrinsics, rotation=gt.rotation,
                            translation=gt.translation + [1.5, 0.0, 0.0])
    s.set_calibration(gt, lock=False)
    monkeypatch.setattr(api, "calibrate", lambda *a, **k: bad)
    up = s.calibrate()
    assert up.attempted and not up.accepted and s.calibration is gt
    assert up.candidate_score < up.current_score
    s.set_calibration(bad, lock=False)
    monkeypatch.setattr(api, "calibrate", lambda *a, **k: gt)
    up = s.calibrate()
    assert up.accepted and s.calibration is gt and up.candidate_score > up.current_score
    s.set_calibration(bad, lock=True)  # a surveyed pose is never replaced automatically
    up = s.calibrate()
    assert not up.attempted and s.calibration is bad


def test_pseudo_labels_through_the_true_pose_agree_with_ground_truth(site, frames):
    s = _matcher().oneshot(site.intrinsics, min_frames=100)
    _observe(s, frames[:4])
    s.set_calibration(site.T_cam_lidar)
    tp = n_pl = n_gt = 0
    for obs, t, f in zip(s.buffer, s.pseudo_labels(), frames):
        gt = f.match_matrix[np.ix_(obs.kept_2d, obs.kept_3d)]
        tp, n_pl, n_gt = tp + int((t.positive & gt).sum()), n_pl + t.n_pairs, n_gt + int(gt.sum())
        assert not (t.positive & t.negative).any()
        assert np.all((t.weight > 0) == t.positive) and t.weight.max() <= 1.0
        assert not (t.negative & gt).any()  # a true match is never used as a negative
    assert tp / n_pl >= 0.95 and tp / n_gt >= 0.85


def test_weighted_loss_ignores_zero_weight_rows_and_other_frames():
    from xcalib.models.base import TrainLogits

    class B:
        seg_2d, seg_3d = torch.tensor([0, 0, 1]), torch.tensor([0, 0, 1])

        def same_frame(self):
            return self.seg_2d[:, None] == self.seg_3d[None]

    pos = torch.tensor([[1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.bool)
    neg = ~pos
    w = torch.tensor([[0.9, 0, 0], [0, 0.0, 0], [0, 0, 0.5]])  # row 1: weight 0
    L = torch.tensor([[5.0, -5.0, 9.0], [0.0, 0.0, 9.0], [9.0, 9.0, 5.0]])
    base = weighted_matching_loss([TrainLogits(L)], B(), pos, w, neg)
    other = L.clone()
    other[0, 2], other[2, 0] = -9.0, 30.0  # scores between different frames are masked
    assert torch.allclose(weighted_matching_loss([TrainLogits(other)], B(), pos, w, neg), base)
    only_rows = torch.tensor([[5.0, -5.0, 0.0], [7.0, 0.0, 0.0], [0.0, 0.0, 5.0]])
    a = weighted_matching_loss([TrainLogits(only_rows)], B(), pos, w, torch.zeros_like(neg))
    only_rows[1, 0] = -7.0
    b = weighted_matching_loss([TrainLogits(only_rows)], B(), pos, w, torch.zeros_like(neg))
    assert torch.allclose(a, b)  # with no negatives allowed, a zero-weight row contributes nothing
    wrong = L.clone()
    wrong[0] = torch.tensor([-5.0, 5.0, 9.0])
    assert weighted_matching_loss([TrainLogits(wrong)], B(), pos, w, neg) > base + 1.0
    logit = weighted_matching_loss([TrainLogits(L, "logit")], B(), pos, w, neg)
    assert logit > base  # the balanced BCE is added for "logit" outputs


def test_augmentation_moves_boxes_consistently_through_the_pose(site, frames):
    s = _matcher().oneshot(site.intrinsics, min_frames=100)
    _observe(s, frames[:4])
    s.set_calibration(site.T_cam_lidar)
    T = site.T_cam_lidar
    targets = s.pseudo_labels()
    rng = np.random.default_rng(0)
    still = GeometricAugment(site.intrinsics, T[:3, :3], T[:3, 3], shift_m=0.0, p_view=0.0, p_blank=0.0)
    moved = GeometricAugment(site.intrinsics, T[:3, :3], T[:3, 3], shift_m=10.0, p_move=1.0, p_view=0.5, p_blank=0.0)
    blank = GeometricAugment(site.intrinsics, T[:3, :3], T[:3, 3], p_blank=1.0, p_virtual=0.0)
    virtual = GeometricAugment(site.intrinsics, T[:3, :3], T[:3, 3], p_blank=0.0, p_virtual=1.0)
    before, after, n_virtual = [], [], 0
    for obs, t in zip(s.buffer, targets):
        fi = obs.inputs(16, rng)
        f0, t0 = still.apply(fi, t, rng)
        np.testing.assert_array_equal(f0.boxes_2d, fi.boxes_2d)
        np.testing.assert_array_equal(t0.positive, t.positive)
        fb, _ = blank.apply(fi, t, rng)
        assert not fb.crops_2d.any() and not fb.crops_3d.any() and fi.crops_2d.any()
        fv, tv = virtual.apply(fi, t, rng)
        v = fv.kept_2d < 0  # virtual rows: blank image crop, one positive each, on a 3D box unmatched before
        assert not fv.crops_2d[v].any() and np.all(tv.positive[v].sum(1) == 1)
        assert np.all(tv.weight[v][tv.positive[v]] == 0.5)
        assert not t.positive[:, np.flatnonzero(tv.positive[v].any(0))].any()
        n_virtual += int(v.sum())
        f1, t1 = moved.apply(fi, t, rng)
        assert f1.crops_2d.shape[0] == f1.boxes_2d.shape[0] == t1.positive.shape[0]
        assert f1.crops_3d.shape[0] == f1.boxes_3d.shape[0] == t1.positive.shape[1]
        assert not np.allclose(f1.boxes_3d[:, :2], fi.boxes_3d[:, :2])
        i, j = np.nonzero(t.positive)
        before += list(np.diag(_iou(fi.boxes_2d[i].astype(float), _rects(fi.boxes_3d.astype(float), site.intrinsics,
                                                                         T[:3, :3], T[:3, 3])[j])))
        i, j = np.nonzero(t1.positive)
        after += list(np.diag(_iou(f1.boxes_2d[i].astype(float), _rects(f1.boxes_3d.astype(float), site.intrinsics,
                                                                        T[:3, :3], T[:3, 3])[j])))
        assert np.all((f1.boxes_2d[:, 2] <= 640) & (f1.boxes_2d[:, 0] >= 0))
    assert len(after) >= 5 and n_virtual >= 3
    assert abs(np.median(after) - np.median(before)) < 0.1  # moved pairs stay as consistent as real ones


def test_projection_targets_use_matched_2d_boxes_else_the_clipped_projection(site, frames):
    s = _matcher().oneshot(site.intrinsics, min_frames=100)
    _observe(s, frames[:3])
    s.set_calibration(site.T_cam_lidar)
    T = site.T_cam_lidar
    aug = GeometricAugment(site.intrinsics, T[:3, :3], T[:3, 3])
    n_proj = 0
    for obs, t in zip(s.buffer, s.pseudo_labels()):
        fi = obs.inputs(16, np.random.default_rng(0))
        r = aug.project(fi, t)
        assert r.shape == (fi.num_3d, 4)
        i, j = np.nonzero(t.positive)
        np.testing.assert_array_equal(r[j], fi.boxes_2d[i])
        other = np.setdiff1d(np.flatnonzero(np.isfinite(r).all(1)), j)
        raw = _rects(fi.boxes_3d.astype(float), site.intrinsics, T[:3, :3], T[:3, 3])[other]
        np.testing.assert_allclose(r[other][:, [0, 2]], np.clip(raw[:, [0, 2]], 0, 640))
        np.testing.assert_allclose(r[other][:, [1, 3]], np.clip(raw[:, [1, 3]], 0, 480))
        n_proj += len(other)
    assert n_proj >= 1


def test_fastmatch_box_gain_rescale_keeps_scores_and_rejects_bad_gains(frames):
    m = _matcher()
    f = frames[0]
    before = m.match(*f.inputs(), validate="off").similarity
    m.model.set_box_gain(30.0)
    np.testing.assert_allclose(m.match(*f.inputs(), validate="off").similarity, before, atol=1e-5)
    assert m.model.box_gain == 30.0 and m.model.config["box_gain"] == 30.0
    m.model.set_box_gain(60.0, rescale=False)  # the box term is 4x stronger now
    assert not np.allclose(m.match(*f.inputs(), validate="off").similarity, before, atol=1e-5)
    with pytest.raises(ValueError, match="box_gain must be a finite number > 0, got -1.0"):
        m.model.set_box_gain(-1.0)


def test_adapt_before_any_calibration_is_a_clear_error(site, frames):
    s = _matcher().oneshot(site.intrinsics, min_frames=100)
    _observe(s, frames[:2])
    with pytest.raises(NotCalibratedError, match="no calibration yet after 2 observed frame"):
        s.adapt(steps=5)


def test_image_size_change_mid_session_is_rejected_and_not_buffered(site, frames):
    s = _matcher().oneshot(site.intrinsics, min_frames=100)
    _observe(s, frames[:1])
    f = frames[1]
    small = np.zeros((240, 320, 3), np.uint8)
    with pytest.raises(ImageSizeChangedError, match=r"320x240 px but this session's camera is 640x480"):
        s.observe(small, f.point_cloud, f.bboxes_2d / 2, f.bboxes_3d, validate="off")
    assert len(s.buffer) == 1 and s.n_observed == 1


def test_too_few_pseudo_labels_warn_and_leave_weights_untouched(site, frames):
    m = _matcher()
    s = m.oneshot(site.intrinsics, min_frames=100)
    _observe(s, frames[:3])
    T = site.T_cam_lidar.copy()
    T[:3, :3] = np.diag([-1.0, 1.0, -1.0]) @ T[:3, :3]  # camera turned around: nothing projects into view
    s.set_calibration(T)
    before = {k: v.clone() for k, v in m.model.state_dict().items()}
    with pytest.warns(RuntimeWarning, match="pseudo-labelled pair"):
        rep = s.adapt(steps=5)
    assert not rep.trained and rep.n_pairs < 8
    assert all(torch.equal(before[k], v) for k, v in m.model.state_dict().items())


def test_adapt_learns_the_pseudo_labels_and_reloads_bit_exactly(site, frames, tmp_path, monkeypatch):
    m = _matcher()
    s = m.oneshot(site.intrinsics, min_frames=100, seed=0)
    _observe(s, frames)
    s.set_calibration(site.T_cam_lidar)
    T = site.T_cam_lidar
    aug = GeometricAugment(site.intrinsics, T[:3, :3], T[:3, 3])

    def box_err() -> float:  # predicted 2D box of every 3D box vs the pose's, image fractions / log sizes
        from xcalib.models.inputs import ModelBatch
        from xcalib.oneshot.adapt import _box_space

        errs = []
        for obs, t in zip(s.buffer, s.pseudo_labels()):
            fi = obs.inputs(16, np.random.default_rng(0))
            tgt = _box_space(m.model, aug.project(fi, t), fi.image_size)
            with torch.no_grad():
                pred = m.model.embed(ModelBatch.from_frames([fi], "cpu")).extra["box_lid"].numpy()
            ok = np.isfinite(tgt).all(1)
            errs.append(((pred[ok] - tgt[ok]) ** 2).sum(1))
        return float(np.concatenate(errs).mean())

    err0 = box_err()
    rep = s.adapt(steps=40, holdout=0.25)
    assert rep.trained and not rep.reverted and rep.n_heldout_frames == 2
    assert box_err() < 0.5 * err0  # the geometry branch learned the pose's projection
    g = rep.box_gain  # "auto": the own gain 1 or the one from the detector-vs-pose residual, whichever held out better
    assert [t.chosen for t in rep.gain_trials].count(True) == 1 and len(rep.gain_trials) == 2
    assert rep.gain_trials[0].box_gain == 1.0 and 1.0 < rep.gain_trials[1].box_gain <= 100.0
    assert g == next(t.box_gain for t in rep.gain_trials if t.chosen)
    assert m.model.box_gain == g and m.config["box_gain"] == g
    assert rep.loss_last < rep.loss_first
    assert rep.top1_after >= rep.top1_before
    # the base weights are kept: they differ from the adapted ones and come back exactly
    assert not all(torch.equal(s.base_state[k], v) for k, v in m.model.state_dict().items())
    paths = s.save(tmp_path / "adapted")
    assert json.loads(paths["oneshot"].read_text())["adapt"][0]["trained"] is True
    assert CalibrationResult.load(paths["calibration"]).pose_error(site.T_cam_lidar)[0] < 1e-6
    again = Matcher.from_pretrained("fastmatch", weights=tmp_path / "adapted", device="cpu")
    assert _states_equal(again.model, m.model) and again.model.box_gain == g
    f = frames[0]
    np.testing.assert_array_equal(again.match(*f.inputs(), validate="off").similarity,
                                  m.match(*f.inputs(), validate="off").similarity)
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path / "home"))
    s.save_site("my_site")
    assert _states_equal(Matcher.from_pretrained("fastmatch", site="my_site", device="cpu").model, m.model)
    with pytest.raises(ValueError, match="plain folder name"):
        s.save_site("../escape")
    s.reset_weights()
    assert all(torch.equal(s.base_state[k], v) for k, v in m.model.state_dict().items())
    assert m.model.box_gain == 1.0 and m.config["box_gain"] == 1.0


def test_box_gain_selection_keeps_the_best_held_out_candidate_bit_exactly(site, frames, monkeypatch):
    import xcalib.oneshot.adapt as adapt

    def session(seed=0):
        m = _matcher()
        s = m.oneshot(site.intrinsics, min_frames=100, seed=seed)
        _observe(s, frames)
        s.set_calibration(site.T_cam_lidar)
        return m, s

    m, s = session()
    with pytest.raises(ValueError, match="box_gain must be a number"):
        s.adapt(steps=2, box_gain="bogus")
    assert len(s.adapt(steps=2, box_gain=(None, 1.0)).gain_trials) == 1  # the own gain is 1: one candidate
    s.reset_weights()
    # the selection rule alone: held-out Top-1 first, then held-out loss, a tie keeps the first candidate
    top1 = {1.0: 0.5, 7.0: 0.9, 9.0: 0.9}
    monkeypatch.setattr(adapt, "pseudo_top1", lambda model, *a: top1.get(model.box_gain, 0.1))
    monkeypatch.setattr(adapt, "pseudo_loss", lambda model, *a: {7.0: 0.3, 9.0: 0.2}.get(model.box_gain, 1.0))
    rep = s.adapt(steps=2, box_gain=(None, 7.0, 9.0))
    assert [t.top1 for t in rep.gain_trials] == [0.5, 0.9, 0.9] and [t.chosen for t in rep.gain_trials] == [0, 0, 1]
    assert rep.box_gain == 9.0 == m.model.box_gain and rep.top1_after == 0.9 and "9: held-out Top-1" in rep.message
    s.reset_weights()
    top1[9.0] = 0.5
    monkeypatch.setattr(adapt, "pseudo_loss", lambda model, *a: 0.5)
    rep = s.adapt(steps=2, box_gain=(None, 9.0))  # equal scores: the simpler first candidate (own gain)
    assert [t.chosen for t in rep.gain_trials] == [True, False] and m.model.box_gain == 1.0
    monkeypatch.undo()
    # the kept candidate is exactly what training that gain alone gives (same start, same batches)
    m, s = session(seed=3)
    rep = s.adapt(steps=15, holdout=0.25, box_gain=(None, 40.0))
    assert rep.trained and len(rep.gain_trials) == 2 and np.isfinite([t.loss for t in rep.gain_trials]).all()
    m2, s2 = session(seed=3)
    s2.adapt(steps=15, holdout=0.25, box_gain=rep.box_gain)
    assert _states_equal(m.model, m2.model) and m.model.box_gain == m2.model.box_gain == rep.box_gain


def test_observe_crops_once_and_matches_like_matcher(site, frames):
    m = _matcher()
    s = m.oneshot(site.intrinsics, min_frames=100)
    f = frames[0]
    s.observe_frame(f, validate="off")
    obs = s.buffer[0]
    cfg = m.crop_config
    sim_session = m.similarity(obs.inputs(cfg.point_cloud_size, np.random.default_rng(cfg.seed)))
    mr = m.match(*f.inputs(), validate="off")
    np.testing.assert_array_equal(obs.kept_2d, mr.kept_2d_indices)
    np.testing.assert_array_equal(obs.kept_3d, mr.kept_3d_indices)
    np.testing.assert_allclose(sim_session, mr.similarity, atol=1e-6)
    assert obs.frame.image.strides[:2] == (0, 0)  # no image pixels kept in the buffer


def test_set_calibration_rejects_failed_results_and_non_rotations(site):
    s = _matcher().oneshot(site.intrinsics)
    with pytest.raises(ValueError, match="failed"):
        s.set_calibration(CalibrationResult(success=False, message="nope"))
    with pytest.raises(ValueError, match="not a rotation"):
        s.set_calibration(np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="4x4"):
        s.set_calibration(np.eye(3))
    with pytest.raises(ValueError, match="mode"):
        _matcher().oneshot(site.intrinsics, mode="everything")


def test_cli_bootstrap_installs_site_weights(site, frames, tmp_path, monkeypatch, capsys):
    from xcalib.cli import main
    from xcalib.io.hdf5 import CacheWriter

    cache = tmp_path / "rec.h5"
    with CacheWriter(cache, camera_names=[site.camera_name], lidar_name=site.lidar_name,
                     label_sensor=site.camera_name) as w:
        for f in generate_frames(site, 6, seed=4, render_images=False):
            f.match_matrix = None  # unlabelled recording
            w.add(f)
    K = tmp_path / "K.json"
    K.write_text(json.dumps(site.intrinsics.to_dict()))
    monkeypatch.setenv("XCALIB_HOME", str(tmp_path / "home"))
    rc = main(["bootstrap", str(cache), "--intrinsics", str(K), "--site", "cli_site", "--init", "scratch",
               "--steps", "5", "--limit", "5"])  # the human-readable summary (the --json one: test_cli_commands)
    assert rc == 0
    out = capsys.readouterr().out
    assert "calibration OK" in out and "trained fastmatch" in out and "held-out Top-1" in out
    assert "box-geometry gain kept on the held-out frames" in out and ", kept)" in out
    m = Matcher.from_pretrained("fastmatch", site="cli_site", device="cpu")
    assert f"weights: {m.weights_path}" in out
    assert m.weights_path.parent == tmp_path / "home" / "sites" / "cli_site"
    assert (m.weights_path.parent / "calibration.json").is_file()
    rc = main(["bootstrap", str(cache), "--site", "x", "--no-install"])
    assert rc == 2  # --no-install needs --out


def test_heldout_figure_is_reported_only_when_an_independent_pose_agrees(site, frames, monkeypatch):
    """Issue 17: the bootstrap's held-out Top-1 is measured on >= 4 frames left out of training and
    reported only when a pose calibrated without those frames gives the same matches and figure."""
    import xcalib.calib.api as api
    from xcalib.geometry.rotations import rotvec_to_matrix
    from xcalib.oneshot.heldout import MIN_HELDOUT_FRAMES, check_heldout

    s = _matcher().oneshot(site.intrinsics, min_frames=100, seed=0)
    _observe(s, frames)
    s.set_calibration(site.T_cam_lidar)
    rep = s.adapt(steps=2, holdout=0.25, min_holdout=MIN_HELDOUT_FRAMES, box_gain=None)
    assert rep.n_heldout_frames == 4 and rep.n_train_frames == 4 and len(rep.heldout_frames) == 4
    from xcalib.calib.config import CalibConfig

    ok = check_heldout(s, rep.heldout_frames, calib_config=CalibConfig(max_rot_std_deg=2.0, max_trans_std_m=1.0))
    assert ok.n_frames == 4 and ok.n_pairs >= 12 and ok.verified, ok.message
    assert ok.reported_top1 == ok.top1 and abs(ok.top1 - ok.top1_independent) <= 0.05 and ok.label_agreement >= 0.9
    assert ok.interval[0] <= ok.top1 <= ok.interval[1] and ok.interval[1] - ok.interval[0] > 0.05  # 32 matches

    T = site.T_cam_lidar
    off = CalibrationResult(success=True, intrinsics=site.intrinsics,
                            rotation=rotvec_to_matrix(np.array([0.0, 0.2, 0.0])) @ T[:3, :3], translation=T[:3, 3])
    monkeypatch.setattr(api, "calibrate", lambda *a, **k: off)  # an "independent" pose 11 degrees away
    bad = check_heldout(s, rep.heldout_frames)
    assert not bad.verified and bad.reported_top1 is None and "disagree" in bad.message
    monkeypatch.setattr(api, "calibrate", lambda *a, **k: CalibrationResult(success=False, message="too few pairs"))
    refused = check_heldout(s, rep.heldout_frames)
    assert not refused.verified and "refused" in refused.message and refused.reported_top1 is None
    assert check_heldout(s, rep.heldout_frames[:2]).reported_top1 is None  # too few frames: not reported
