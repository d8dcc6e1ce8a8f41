"""``scripts/refusal_audit.py`` (issue 25, session 10): which check refuses right poses, from the
refusal records stored with realism runs. Synthetic records (no real data, no calibration)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _mod():
    spec = importlib.util.spec_from_file_location("refusal_audit", ROOT / "scripts" / "refusal_audit.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _rec(seed, refusal=None, delta=None, success=False, err=None):
    r = {"seed": seed, "success": success}
    if refusal is not None:
        r["refusal"] = refusal
    if delta is not None:
        r["refused_delta"] = delta
    if success:
        r["rot_deg"], r["trans_m"] = err
    return r


def test_audit_counts_right_and_wrong_refusals():
    m = _mod()
    recs = [_rec(0, "few_objects", [0.1, 0, 0, 0.05, 0, 0]),       # right within 0.3 / 0.2
            _rec(1, "few_objects", [0.6, 0, 0, 0, 0.3, 0]),        # right within 1 / 0.5 only
            _rec(2, "few_objects", [0, 1.2, 0, 0, 0, 0]),          # wrong (rotation)
            _rec(3, "poorly_constrained", [0, 0, 0.2, 0, 0, 0.6]),  # wrong (translation)
            _rec(4, "poorly_constrained"),                         # no refused pose stored
            _rec(5, success=True, err=(0.1, 0.1))]                 # successes are not refusals
    a = m.audit(recs)
    assert (a["few_objects"]["strict"], a["few_objects"]["line"], a["few_objects"]["wrong"]) == (1, 2, 1)
    assert (a["poorly_constrained"]["line"], a["poorly_constrained"]["wrong"], a["poorly_constrained"]["unknown"]) == (0, 1, 1)
    t = m.totals({"c1": a, "c2": a})
    assert t["few_objects"]["line"] == 4 and t["poorly_constrained"]["unknown"] == 2


def test_latest_records_and_pairs():
    m = _mod()
    runs = {"old": {"conditions": [{"condition": "clean", "per_site": [_rec(9, "few_objects", [0.5, 0, 0, 0, 0, 0])]}]},
            "new": {"box_noise_px": None, "conditions": [
                {"condition": "clean", "per_site": [_rec(9, "principal_point_unverifiable", [0.03, 0, 0, 0.01, 0, 0])]},
                {"condition": "principal_point+3%W", "per_site": [_rec(9, "focal_unverifiable", [1.4, 0, 0, 0.28, 0, 0])]}]},
            "noisy": {"box_noise_px": 4.0, "conditions": [{"condition": "clean", "per_site": [_rec(9, success=True, err=(0.1, 0.1))]}]}}
    latest = m.latest_records(runs)
    assert latest["clean"][0] == "new" and latest["clean@4px"][0] == "noisy"
    assert m.latest_records(runs, since="noisy").keys() == {"clean@4px"}
    p = m.pairs(latest)
    assert len(p) == 1 and p[0][:3] == ("clean", 9, "principal_point_unverifiable")
    assert p[0][4] == [("principal_point+3%W", "focal_unverifiable", (1.4, 0.28))]


def test_committed_realism_refusals_are_audited():
    """The committed realism file holds refusal records with codes and refused poses (skips nothing:
    the file is in the repository)."""
    m = _mod()
    import json

    latest = m.latest_records(json.loads(m.RESULTS.read_text())["runs"], since=m.SINCE)
    per = {c: m.audit(r) for c, (_, r) in latest.items()}
    tot = m.totals(per)
    assert tot and sum(v["strict"] + v["wrong"] for v in tot.values()) > 0


def test_model_information_profile_sees_a_principal_point_error():
    """``scripts/model_information.py``: on a synthetic pinhole site with the exact camera, a
    principal point 3 % of the width off raises the robust cost of the true matches and turns the
    refitted pose; the exact camera costs nothing more than itself."""
    import numpy as np

    from xcalib.calib.inputs import prepare_frames
    from xcalib.calib.pose import Pose
    from xcalib.data.synth import generate_frames, sample_site

    spec = importlib.util.spec_from_file_location("model_information", ROOT / "scripts" / "model_information.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    site = sample_site(0, "roadside")
    frames = generate_frames(site, 4, seed=5, render_images=False, lidar=False)
    cframes, intr, _ = prepare_frames(frames, site.intrinsics)
    T = np.asarray(site.T_cam_lidar)
    r = mod.profile(cframes, intr, Pose(T[:3, :3], T[:3, 3]), {"pp+3%W": (0.03, 1.0), "none": (0.0, 1.0)})
    assert r["objects"] >= 4 and r["pairs"] > r["objects"]
    assert r["pp+3%W"]["dcost"] > 0 and r["pp+3%W"]["pose_err"][0] > 0.5
    assert abs(r["none"]["dcost"]) < 1e-6 * max(r["cost_true"], 1.0)
