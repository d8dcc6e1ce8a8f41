"""The lens-misfit check (``misfit.lens_check``): a fisheye camera given with pinhole intrinsics is
named, a pinhole site is left alone. At the true pose with the true matches (the search itself:
benchmarks/bench_camera_models.py, rows "<model> as pinhole")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from xcalib.calib.cost import FocalScaleTerm, WideLensTerm
from xcalib.calib.diagnostics import NoiseModel
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.misfit import LENS_ALT_GAIN, LENS_MIN_GAIN, LENS_MIN_XI, lens_check, lens_checks
from xcalib.calib.pose import Pose
from xcalib.calib.refine import build_cost, match_all
from xcalib.calib.cost import Occlusion
from xcalib.data.synth import generate_frames, sample_site
from xcalib.geometry import CameraIntrinsics
from xcalib.geometry.camera_models import Unified


def _case(model: str, hfov: float, seed: int, as_pinhole: bool, n_frames: int = 5):
    site = sample_site(seed, camera_model=model, hfov_deg=hfov, width=1280, height=800, box_noise_px=1.0)
    frames = generate_frames(site, n_frames, seed=seed, render_images=False, lidar=False)
    truth = Pose(site.T_cam_lidar[:3, :3], site.T_cam_lidar[:3, 3])
    cframes, cam, _ = prepare_frames(frames, site.intrinsics)
    pairs = match_all(cframes, cam, truth.R, truth.t)  # the true matches (through the true lens)
    intr = cam
    if as_pinhole:  # the user's mistake: the fisheye's fx, fy, cx, cy as a pinhole
        intr = CameraIntrinsics(cam.fx, cam.fy, cam.cx, cam.cy, None, cam.width, cam.height)
    return cframes, pairs, intr, truth


@pytest.mark.parametrize("model,hfov,seed", [("kannala_brandt", 185.0, 0), ("double_sphere", 150.0, 1)])
def test_fisheye_given_as_pinhole_is_named(model, hfov, seed):
    cframes, pairs, intr, truth = _case(model, hfov, seed, as_pinhole=True)
    chk, msg = lens_check(cframes, pairs, intr, truth, NoiseModel(), 2.0, Occlusion(), places=None)
    assert chk.name == "lens" and chk.flagged, chk.detail
    assert chk.statistic > LENS_MIN_GAIN
    assert "wider-angle lens" in msg and "pinhole" in msg and "model" in msg and "--intrinsics" in msg


def test_pinhole_site_is_not_flagged():
    cframes, pairs, intr, truth = _case("pinhole", 90.0, 0, as_pinhole=False)
    assert isinstance(intr, CameraIntrinsics)
    chk, msg = lens_check(cframes, pairs, intr, truth, NoiseModel(), 2.0, Occlusion(), places=None)
    assert not chk.flagged and msg is None, chk.detail
    assert chk.statistic < 1.0  # no gain from widening a true pinhole
    assert "xi 0.0" in chk.detail  # it fits no bend (xi ~0)


def test_a_given_wide_angle_model_is_not_checked():
    cframes, pairs, cam, truth = _case("kannala_brandt", 150.0, 0, as_pinhole=False, n_frames=3)
    chk, msg = lens_check(cframes, pairs, cam, truth, NoiseModel(), 2.0, Occlusion())
    assert not chk.flagged and msg is None and "not checked" in chk.detail


def test_wide_lens_term_at_zero_is_the_pinhole_and_widens_the_rim():
    intr = CameraIntrinsics(600.0, 610.0, 640.0, 400.0, [-0.05, 0.01, 1e-4, -2e-4], 1280, 800)
    term = WideLensTerm(intr)
    P = np.array([[0.0, 0.0, 5.0], [2.0, -1.0, 5.0], [6.0, 2.0, 4.0]])
    from xcalib.geometry import project_points
    uv0, _ = project_points(P, intr)
    uv, ok = term.camera(0.0).project(P)
    assert ok.all() and np.allclose(uv, uv0, atol=1e-9)
    wide, _ = term.camera(1.5).project(P)
    assert np.allclose(wide[0], uv0[0])  # the same image centre ...
    r0, r1 = np.linalg.norm(uv0[2] - [640, 400]), np.linalg.norm(wide[2] - [640, 400])
    assert r1 < r0  # ... and the rim pulled in (a wider lens)
    assert isinstance(term.camera(1.5), Unified) and 0 < LENS_MIN_XI < 1
    assert not WideLensTerm.applies(CameraIntrinsics(600, 600, 640, 400, [0, 0, 0, 0, 0.1]))
    assert FocalScaleTerm.name != WideLensTerm.name


def test_consensus_searches_fisheye_lenses_when_asked():
    from xcalib.calib.consensus import ConsensusConfig, consensus_matches, searched_intrinsics
    from xcalib.geometry.camera_models import KannalaBrandt

    kb = searched_intrinsics(1280, 800, 180.0, "equidistant")
    assert isinstance(kb, KannalaBrandt) and abs(kb.fx - 640 / (np.pi / 2)) < 1e-9
    with pytest.raises(ValueError, match="fisheye_fov_deg"):
        ConsensusConfig(fisheye_fov_deg=(300.0,))
    site = sample_site(0, camera_model="kannala_brandt", hfov_deg=185.0, width=1280, height=800, box_noise_px=1.0)
    frame = generate_frames(site, 1, seed=0, render_images=False, lidar=False)[0]
    cm = consensus_matches(frame, None, ConsensusConfig(fov_deg=(90.0,), fisheye_fov_deg=(185.0,)))
    assert isinstance(cm.intrinsics, KannalaBrandt)  # the fisheye guess explains the frame best
    M = np.asarray(frame.match_matrix)
    correct = sum(M[i, j] > 0 for i, j in cm.pairs)
    assert len(cm.pairs) >= 8 and correct >= 0.8 * len(cm.pairs)


def test_wide_renderer_draws_faces_beside_the_optical_plane_with_curved_sides():
    from xcalib.data.synth.render import _fill_wide

    site = sample_site(0, camera_model="kannala_brandt", hfov_deg=185.0, width=640, height=400)
    T_world_cam = np.linalg.inv(site.T_cam_world)
    # a face 8 m away towards the image corner, 93-103 degrees off the optical axis (behind the
    # image plane: Z < 0), 1 m each side of that diagonal
    phi = np.arctan2(200.0, 320.0)
    d, n = np.array([np.cos(phi), np.sin(phi)]), np.array([-np.sin(phi), np.cos(phi)])

    def at(deg, side):
        th = np.radians(deg)
        return np.array([*(8 * np.sin(th) * d + side * n), 8 * np.cos(th)])

    cam = np.array([at(93, -1), at(103, -1), at(103, 1), at(93, 1)])
    assert np.all(cam[:, 2] <= 0)
    world = cam @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    img = np.zeros((400, 640, 3), np.uint8)
    out = _fill_wide(img, site, world[None], [np.array([200.0, 200.0, 200.0])], [(0, 1)])
    drawn = out.sum(-1) > 0
    assert drawn.sum() > 20  # drawn, not dropped for Z <= 0
    uv, ok = site.intrinsics.project(cam)
    assert ok.all()
    ys, xs = np.nonzero(drawn)
    # the drawn face reaches its projected corners' box (curved sides bulge past it, never short of it)
    lo, hi = np.clip(uv.min(0), 0, [639, 399]), np.clip(uv.max(0), 0, [639, 399])
    assert xs.min() <= lo[0] + 1.5 and xs.max() >= hi[0] - 1.5
    assert ys.min() <= lo[1] + 1.5 and ys.max() >= hi[1] - 1.5


def test_unified_lens_given_as_pinhole_with_its_own_focal_is_named():
    # a Mei/Kalibr omni camera's fx is f (1 + xi): given as pinhole the focal is ~2.1x too long as
    # well; the lens fit starts there too (focal / (1 + xi)) and names the lens
    cframes, pairs, intr, truth = _case("unified", 120.0, 1, as_pinhole=True, n_frames=4)
    (chk, msg), (alt, alt_msg) = lens_checks(cframes, pairs, intr, truth, NoiseModel(), 2.0, Occlusion())
    assert chk.flagged and alt.flagged, chk.detail
    assert "xi 1.1" in chk.detail or "xi 1.2" in chk.detail  # the site's xi is 1.1
    assert "wider-angle lens" in msg and "changed focal length" in alt_msg


def test_a_wrong_focal_on_a_pinhole_is_not_blamed_on_the_lens():
    cframes, pairs, intr, truth = _case("pinhole", 90.0, 0, as_pinhole=False, n_frames=4)
    intr = replace(intr, fx=intr.fx * 1.1, fy=intr.fy * 1.1)
    (chk, msg), (alt, alt_msg) = lens_checks(cframes, pairs, intr, truth, NoiseModel(), 2.0, Occlusion())
    assert not chk.flagged and not alt.flagged and msg is None and alt_msg is None, alt.detail
    assert alt.limit == LENS_ALT_GAIN < LENS_MIN_GAIN


class _Searches:
    """The misfit searches' results, canned: (second pose, lens checks, mirror), the searches'
    "nothing found" tuples (their length as ``api._second_pose`` gives it on no leftover boxes; the
    mirror's has two fewer entries: no pose distance, no admissibility)."""

    def __init__(self, lens, intr, pose):
        from xcalib.calib.api import _second_pose
        from xcalib.calib.config import CalibConfig

        second = _second_pose([], [], intr, pose, CalibConfig(), Occlusion())
        self.out = [second, lens, (0.0, 0, *second[4:])]

    def result(self, k):
        return self.out[k]


@pytest.mark.parametrize("lens_explains", [False, True])
def test_a_fired_focal_check_names_the_lens_when_the_lens_explains_the_boxes(lens_explains):
    # the attribution rule of calib.api: the lens check did not fire on its own, the focal-length
    # check did; the lens is named only when its alternative verdict supports it
    from xcalib.calib.api import _misfit_checks
    from xcalib.calib.config import CalibConfig
    from xcalib.calib.context import FitContext
    from xcalib.calib.diagnostics import CalibDiagnostics, MisfitCheck

    cframes, pairs, intr, truth = _case("pinhole", 90.0, 0, as_pinhole=False, n_frames=4)
    intr = replace(intr, fx=intr.fx * 1.15, fy=intr.fy * 1.15)
    lens = (MisfitCheck("lens", 1.0, LENS_MIN_GAIN, False, "primary"), None)
    alt = (MisfitCheck("lens", 5.0, LENS_ALT_GAIN, True, "alternative"), "model misfit: ... a wider-angle lens ...") \
        if lens_explains else (MisfitCheck("lens", 1.0, LENS_ALT_GAIN, False, "alternative"), None)
    ctx = FitContext(cframes, pairs, intr, truth, NoiseModel(), 2.0, Occlusion())
    diag = CalibDiagnostics()
    refusal = _misfit_checks(ctx, 100.0, CalibConfig(), diag, cframes, None, _Searches((lens, alt), intr, truth))
    assert refusal is not None
    lens_rows = [c for c in diag.misfit if c.name == "lens"]
    assert len(lens_rows) == 1
    if lens_explains:
        assert refusal.code == "misfit_lens" and "wider-angle lens" in refusal.message
        assert lens_rows[0].detail == "alternative"
    else:
        assert refusal.code == "misfit_focal_length", refusal
        assert lens_rows[0].detail == "primary"


def _free_fits(cframes, pairs, intr, truth, n_always, monkeypatch):
    """(the free lens fit of ``misfit.lens_fit``, its three starts, with the third gated after
    ``n_always`` or not; the fits it ran)."""
    from xcalib.calib import misfit

    s0 = misfit._wide_fit(cframes, pairs, intr, truth, NoiseModel(), 2.0, Occlusion(), (0.0, ((0.0, 1.0),)))[1]
    starts = ((0.0, s0), (misfit.LENS_START_XI, s0), (misfit.LENS_START_XI, s0 / (1 + misfit.LENS_START_XI)))
    built = []
    monkeypatch.setattr(misfit, "build_cost", lambda *a, **k: built.append(1) or build_cost(*a, **k))
    fit = misfit._wide_fit(cframes, pairs, intr, truth, NoiseModel(), 2.0, Occlusion(), (None, starts, n_always))
    monkeypatch.undo()
    return fit, len(built)


def test_the_lens_fits_third_start_runs_only_while_the_lens_question_is_open(monkeypatch):
    from xcalib.calib import misfit

    assert not misfit._lens_open([0.02, 0.0]) and misfit._lens_open([0.02, LENS_MIN_XI])
    # a pinhole site: both first starts come back to the pinhole, the third is not run; the third,
    # run, ends where the first did (to the solver's tolerance)
    cframes, pairs, intr, truth = _case("pinhole", 90.0, 0, as_pinhole=False, n_frames=3)
    gated, n_gated = _free_fits(cframes, pairs, intr, truth, 2, monkeypatch)
    full, n_full = _free_fits(cframes, pairs, intr, truth, 3, monkeypatch)
    assert (n_gated, n_full) == (2, 3)
    assert gated[0] < LENS_MIN_XI and abs(gated[0] - full[0]) < 1e-3
    assert gated[1] == pytest.approx(full[1], rel=1e-5) and gated[2] == pytest.approx(full[2], rel=1e-6)
    # (where a start ends bent the third runs: test_unified_lens_given_as_pinhole_with_its_own_focal_is_named)
