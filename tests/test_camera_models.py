"""Camera models (xcalib.geometry.camera_models): round trips, Jacobians against finite
differences, valid regions, OpenCV agreement, the registry and parameter validation."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from xcalib.geometry import CameraIntrinsics, camera_names, project_points
from xcalib.geometry.camera_models import (EUCM, UCM, DoubleSphere, KannalaBrandt, Pinhole, PinholeRadtan,
                                           Unified, as_camera_model, available_models, get_model,
                                           model_from_dict)

RADTAN = {
    4: (-0.21, 0.04, 0.001, -0.0015),
    5: (-0.21, 0.04, 0.001, -0.0015, 0.003),
    8: (0.12, -0.05, 0.001, -0.002, 0.01, 0.35, 0.02, 0.001),
    12: (0.12, -0.05, 0.001, -0.002, 0.01, 0.35, 0.02, 0.001, 0.001, -0.002, 0.003, 0.001),
    14: (0.12, -0.05, 0.001, -0.002, 0.01, 0.35, 0.02, 0.001, 0.001, -0.002, 0.003, 0.001, 0.01, -0.02),
}

# (camera, largest angle off axis, degrees, the tests draw points up to)
CAMERAS = [
    (Pinhole(fx=500, fy=510, cx=320, cy=240, width=640, height=480), 60),
    *[(PinholeRadtan(fx=500, fy=510, cx=320, cy=240, distortion=d), 45) for d in RADTAN.values()],
    (KannalaBrandt(fx=290, fy=291, cx=640, cy=400, k=(0.02, -0.01, 0.003, -0.0005)), 95),
    (Unified(fx=800, fy=800, cx=640, cy=400, xi=1.2, distortion=(-0.1, 0.02, 0.001, 0.0005)), 95),
    (Unified(fx=600, fy=600, cx=640, cy=400, xi=0.7), 80),
    (UCM(fx=400, fy=400, cx=640, cy=400, alpha=0.6), 95),
    (EUCM(fx=400, fy=400, cx=640, cy=400, alpha=0.6, beta=1.1), 95),
    (DoubleSphere(fx=350, fy=350, cx=640, cy=400, xi=-0.2, alpha=0.6), 95),
]
IDS = [f"{c.name}-{i}" for i, (c, _) in enumerate(CAMERAS)]


def _rays(n, max_deg, seed=0, dist=(0.5, 20.0)):
    rng = np.random.default_rng(seed)
    th = np.radians(rng.uniform(0, max_deg, n))
    ph = rng.uniform(0, 2 * np.pi, n)
    P = np.column_stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    return P * rng.uniform(*dist, n)[:, None]


@pytest.mark.parametrize("cam,max_deg", CAMERAS, ids=IDS)
def test_project_unproject_round_trip(cam, max_deg):
    P = _rays(400, max_deg)
    uv, valid = cam.project(P)
    assert valid.all()
    rays, ok = cam.unproject(uv)
    assert ok.all()
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(rays, P / np.linalg.norm(P, axis=1, keepdims=True), atol=1e-9)
    uv2, ok2 = cam.project(rays)
    assert ok2.all()
    np.testing.assert_allclose(uv2, uv, atol=1e-7)


@pytest.mark.parametrize("cam,max_deg", CAMERAS, ids=IDS)
def test_jacobian_matches_finite_differences(cam, max_deg):
    P = _rays(200, max_deg, seed=1)
    P[0] = [0.0, 0.0, 3.0]  # on the optical axis
    uv, J, valid = cam.project_jacobian(P)
    assert valid.all() and J.shape == (200, 2, 3)
    h = 1e-6
    Jn = np.empty_like(J)
    for k in range(3):
        dP = np.zeros(3)
        dP[k] = h
        Jn[:, :, k] = (cam.project(P + dP)[0] - cam.project(P - dP)[0]) / (2 * h)
    np.testing.assert_allclose(J, Jn, rtol=1e-5, atol=1e-4)
    np.testing.assert_array_equal(uv, cam.project(P)[0])


@pytest.mark.parametrize("cam,max_deg", CAMERAS, ids=IDS)
def test_outside_valid_region_is_flagged_never_wrapped(cam, max_deg):
    limit = math.degrees(cam.max_angle_limit)
    P = np.array([[0.0, 0.0, -2.0], [np.nan, 0.0, 1.0], [0.0, 0.0, 0.0]])
    if limit < 180:  # pinhole: anything at or behind the image plane
        P = np.vstack([P, [1.0, 0.5, -0.5], [1.0, 0.0, 0.0]])
    uv, J, valid = cam.project_jacobian(P)
    assert not valid.any()
    assert np.isnan(uv).all() and np.isnan(J).all()
    # a pixel far out either unprojects to a ray that projects back onto it, or is flagged
    far = np.array([[cam.cx + 1e4 * cam.fx, cam.cy], [np.inf, 0.0], [cam.cx, cam.cy - 50 * cam.fy]])
    rays, ok = cam.unproject(far)
    assert not ok[1] and np.isnan(rays[~ok]).all()
    if ok.any():
        back, ok_back = cam.project(rays[ok])
        assert ok_back.all()
        np.testing.assert_allclose(back, far[ok], rtol=1e-9)
    if not isinstance(cam, (Pinhole, Unified)):
        assert not ok.any()  # these models image a bounded disc


def test_radtan_past_its_turning_point_is_flagged():
    cam = PinholeRadtan(fx=500, fy=500, cx=320, cy=240, distortion=(-0.5, 0.0, 0.0, 0.0))
    # r (1 - 0.5 r^2) turns at r = sqrt(2/3): beyond it, points fold back towards the centre
    assert cam.max_radius == pytest.approx(math.sqrt(2 / 3), rel=2e-3)
    uv, valid = cam.project(np.array([[0.5, 0, 1.0], [1.2, 0, 1.0], [2.0, 0, 1.0]]))
    assert valid.tolist() == [True, False, False]
    assert np.isnan(uv[1:]).all()


@pytest.mark.parametrize("n", sorted(RADTAN))
def test_radtan_agrees_with_opencv(n):
    cam = PinholeRadtan(fx=500, fy=510, cx=320, cy=240, distortion=RADTAN[n])
    P = _rays(300, 40, seed=n)
    uv, valid = cam.project(P)
    ref, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), cam.K, np.array(RADTAN[n]))
    assert valid.all()
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-8)
    und = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, np.array(RADTAN[n]), None, np.eye(3), np.eye(3),
                              (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)).reshape(-1, 2)
    rays, ok = cam.unproject(uv)
    assert ok.all()
    np.testing.assert_allclose(rays[:, :2] / rays[:, 2:], und, atol=1e-6)


def test_kannala_brandt_agrees_with_opencv_fisheye():
    k = (0.02, -0.01, 0.003, -0.0005)
    cam = KannalaBrandt(fx=290, fy=291, cx=640, cy=400, k=k)
    P = _rays(300, 85, seed=3)  # OpenCV's fisheye divides by Z: in front of the camera only
    uv, valid = cam.project(P)
    ref, _ = cv2.fisheye.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), cam.K, np.array(k))
    assert valid.all()
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-8)
    und = cv2.fisheye.undistortPoints(uv.reshape(-1, 1, 2), cam.K, np.array(k),
                                      criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))
    rays, ok = cam.unproject(uv)
    assert ok.all()
    np.testing.assert_allclose(rays[:, :2] / rays[:, 2:], und.reshape(-1, 2), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("cam", [c for c, deg in CAMERAS if deg >= 95], ids=lambda c: c.name)
def test_fields_of_view_up_to_190_degrees(cam):
    # choose the image so that 95 degrees off axis lands inside it
    uv, valid = cam.project(np.array([[math.sin(math.radians(95)), 0.0, math.cos(math.radians(95))]]))
    assert valid[0]
    W = int(math.ceil(2 * (uv[0, 0] - cam.cx))) + 2
    wide = cam.replace(cx=W / 2, cy=W / 4, width=W, height=W // 2)
    h, _ = wide.field_of_view()
    assert h >= 190.0
    # straight behind is still flagged
    assert not wide.project(np.array([[0.0, 0.0, -1.0]]))[1][0]


def test_camera_intrinsics_is_the_pinhole_radtan_case():
    intr = CameraIntrinsics(500, 510, 320, 240, [-0.21, 0.04, 0.001, -0.0015, 0.003], 640, 480)
    cam = as_camera_model(intr)
    assert isinstance(cam, PinholeRadtan) and cam.width == 640
    P = _rays(100, 40, seed=5)
    ref, _ = project_points(P, intr)
    np.testing.assert_allclose(cam.project(P)[0], ref, atol=1e-9)
    assert cam.to_intrinsics() == intr
    plain = as_camera_model(CameraIntrinsics(500, 500, 320, 240))
    assert type(plain) is Pinhole
    assert as_camera_model(cam) is cam
    with pytest.raises(TypeError):
        as_camera_model("pinhole")


def test_registry_names_aliases_and_entry_point_fallback(monkeypatch):
    names = available_models()
    for want in ("pinhole", "pinhole_radtan", "kannala_brandt", "unified", "ucm", "eucm", "double_sphere"):
        assert want in names
    assert get_model("equidistant") is KannalaBrandt
    assert get_model("rational_polynomial") is PinholeRadtan
    assert get_model("DS") is DoubleSphere
    with pytest.raises(ValueError, match="unknown camera model 'scaramuzza'.*kannala_brandt"):
        get_model("scaramuzza")
    # no package metadata: the built-ins still resolve
    monkeypatch.setattr(camera_names, "entry_points", lambda: {})
    assert get_model("eucm") is EUCM


def test_registry_loads_a_third_party_entry_point(monkeypatch):
    class FakeEP:
        def __init__(self, name, value, obj):
            self.name, self.value, self._obj = name, value, obj

        def load(self):
            return self._obj

    class MyPinhole(Pinhole):
        name = "my_pinhole"

    eps = {"my_pinhole": FakeEP("my_pinhole", "pkg:MyPinhole", MyPinhole),
           "broken": FakeEP("broken", "pkg:nothing", object),
           "pinhole": FakeEP("pinhole", "evil:Pinhole", object)}
    monkeypatch.setattr(camera_names, "entry_points", lambda: eps)
    assert get_model("my_pinhole") is MyPinhole
    assert get_model("pinhole") is Pinhole  # a plug-in never replaces a built-in
    with pytest.raises(ValueError, match="not a CameraModel subclass"):
        get_model("broken")


@pytest.mark.parametrize("cam,_", CAMERAS, ids=IDS)
def test_to_dict_round_trip(cam, _):
    d = cam.with_image_size(1280, 800).to_dict()
    back = model_from_dict(d)
    assert back == cam.with_image_size(1280, 800)
    assert d["model"] == cam.name


@pytest.mark.parametrize("d,match", [
    ({"model": "fisheye9", "fx": 1, "fy": 1, "cx": 0, "cy": 0}, "unknown camera model"),
    ({"model": "kannala_brandt", "fx": 1, "fy": 1, "cx": 0, "cy": 0}, r"\.k: missing"),
    ({"model": "kannala_brandt", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "k": [0.1, 0.2]}, "expected 4 coefficients"),
    ({"model": "double_sphere", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "xi": 1.5, "alpha": 0.5}, r"xi: expected a value in \[-1, 1\]"),
    ({"model": "double_sphere", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "xi": 0.1, "alpha": -0.1}, r"alpha: expected"),
    ({"model": "ucm", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "alpha": 1.2}, r"alpha: expected a value in \[0, 1\]"),
    ({"model": "eucm", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "alpha": 0.5, "beta": 0}, r"beta: expected"),
    ({"model": "unified", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "xi": -1}, r"xi: expected"),
    ({"model": "unified", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "xi": 1, "distortion": [1, 2, 3]}, "expected 4"),
    ({"model": "pinhole_radtan", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "distortion": [1, 2, 3]}, "expected 4, 5, 8"),
    ({"model": "pinhole", "fx": -1, "fy": 1, "cx": 0, "cy": 0}, "focal lengths must be positive"),
    ({"model": "pinhole", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "xi": 0.3}, r"\.xi: not a parameter"),
    ({"model": "ds", "fx": 1, "fy": 1, "cx": 0, "cy": "a", "xi": 0, "alpha": 0.5}, "cy: expected a number"),
    ({"model": "kannala_brandt", "fx": 1, "fy": 1, "cx": 0, "cy": 0, "k": [-500, 0, 0, 0]}, "decreases right away"),
])
def test_bad_parameters_name_the_field(d, match):
    with pytest.raises(ValueError, match=match):
        model_from_dict(d)


def test_model_from_dict_without_model_key_is_todays_intrinsics():
    assert type(model_from_dict({"fx": 1, "fy": 1, "cx": 0, "cy": 0, "distortion": []})) is Pinhole
    cam = model_from_dict({"fx": 1, "fy": 1, "cx": 0, "cy": 0, "distortion": [0.1, 0, 0, 0]})
    assert type(cam) is PinholeRadtan and cam.distortion == (0.1, 0.0, 0.0, 0.0)
