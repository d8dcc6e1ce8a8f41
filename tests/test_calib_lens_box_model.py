"""The lens check weighs the box model first (``misfit.lens_box_model``): a camera detector's tight
outline, which a unified lens with a small xi partly takes up, is not blamed on the lens (session 13
review: realism ``detector_outline`` 0, a right pose, was refused as ``misfit_lens`` once
``refine_intrinsics="auto"`` kept its exact focal length); a fisheye given as pinhole still is."""

from __future__ import annotations

from xcalib.calib.cost import Occlusion
from xcalib.calib.decision import matched_places
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.misfit import LENS_MIN_GAIN, LENS_MIN_XI, lens_box_model, lens_checks, lens_fit
from xcalib.calib.pose import Pose
from xcalib.calib.refine import estimate_noise, match_all
from xcalib.data.synth.realism import make_realism_case


def test_a_detectors_outline_is_not_blamed_on_the_lens():
    case = make_realism_case("detector_outline", 0, 20)  # pinhole, exact intrinsics, detector outlines
    truth = Pose(case.T_cam_lidar[:3, :3], case.T_cam_lidar[:3, 3])
    cframes, cam, _ = prepare_frames(list(case.frames), case.intrinsics_given)
    pairs = match_all(cframes, cam, truth.R, truth.t, gate_iou=0.3)
    noise = estimate_noise(cframes, pairs, cam, truth.R, truth.t)
    places = len(matched_places(cframes, pairs)[0])
    raw = lens_fit(cframes, pairs, cam, truth, noise, 3.0, Occlusion(), places)
    # without the outline offsets the wide lens would be named: it bends and gains beyond the limit
    assert raw.xi >= LENS_MIN_XI and raw.gain_per_object > LENS_MIN_GAIN, raw
    boxed = lens_box_model(cframes, cam, truth, noise, 3.0, Occlusion(), raw, places)
    assert boxed.gain_per_object < LENS_MIN_GAIN / 2 and boxed.cost_wide <= raw.cost_wide
    (chk, msg), _ = lens_checks(cframes, pairs, cam, truth, noise, 3.0, Occlusion(), places=places)
    assert not chk.flagged and msg is None, chk.detail
    assert "the box model explains it" in chk.detail
