"""``scripts/refusal_audit.py`` (issue 25, session 10): which check refuses right poses, from the
refusal records stored with realism runs. Synthetic records (no real data, no calibration)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

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
    latest = m.latest_records(m.load_runs(), since=m.SINCE)
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


def _parts(n_objects=10, occl=0.1, occl_noise=None, selfcal=None):
    """Stored sigma parts (deg / m 6-vectors) with a frame jackknife, as the realism bench keeps them."""
    return {"jacobian": [0.02] * 6, "halves": [0.01] * 6, "jackknife": None, "frames": [0.03] * 6,
            "occlusion": [occl] * 6, "occlusion_noise": occl_noise, "selfcal": selfcal, "n_objects": n_objects}


def _srec(seed, err, sd, refusal=None, **kw):
    """A realism per-site record with sigma parts: a success stores z_axes, a refusal its refused_delta."""
    r = {"seed": seed, "success": refusal is None, "sigma_axes": [sd] * 6, "sigma_parts": _parts(**kw)}
    if refusal is None:
        r["z_axes"] = list(np.asarray(err, float) / sd)
    else:
        r.update(refusal=refusal, refused_delta=list(err))
    return r



def test_verdict_stats_rebuild_the_data_sigma_and_its_part_beyond_noise():
    """Session 14: the data sigma rebuilt from the parts is the norm of the combined parts; with the
    occlusion shift's noise given, the part beyond it is smaller; the reported bound is bound95's."""
    from xcalib.calib.uncertainty import bound95, combine

    m = _mod()
    rec = _srec(0, [0.1] * 6, 0.2, "poorly_constrained", occl=0.3, occl_noise=[0.1] * 6)
    st = m.verdict_stats(rec)
    r, t = combine(np.full(6, 0.02), None, np.full(6, 0.3), np.full(6, 0.03), None, None)
    assert st[0] == -10 and np.isclose(st[1], bound95([0.2] * 3)) and np.isclose(st[2], bound95([0.2] * 3))
    assert np.isclose(st[3], np.linalg.norm(r)) and np.isclose(st[4], np.linalg.norm(t))
    assert st[5] < st[3] and st[6] < st[4]
    assert m.verdict_stats({"success": True, "sigma_axes": [0.1] * 6}) is None  # no parts stored


def test_stops_names_the_wrong_poses_no_other_check_stops():
    m = _mod()
    recs = m.distinct_records({"r": {"conditions": [{"condition": "c", "per_site": [
        _srec(0, [0.1, 0, 0, 0.05, 0, 0], 0.1, "poorly_constrained", occl=0.5),   # right
        _srec(1, [1.5, 0, 0, 0, 0, 0], 0.1, "poorly_constrained", occl=0.5),      # wrong: the data check alone
        _srec(2, [1.5, 0, 0, 0, 0, 0], 2.0, "poorly_constrained", occl=0.5),      # wrong: the bound stops it too
        _srec(3, [0, 0, 0, 0, 0.9, 0], 0.1, "few_objects", n_objects=3, occl=0.01),  # wrong: its own check only
        _srec(4, [0.1] * 6, 0.1)]}]}})                                             # a right success
    st = m.stops(recs, (0.5, 0.25, 2.0, 1.2))
    assert (st["poorly_constrained"]["right"], st["poorly_constrained"]["wrong"]) == (1, 2)
    alone = {s for _, s, _, also in st["poorly_constrained"]["wrong_sites"] if not also}
    assert alone == {1}
    assert st["few_objects"]["wrong_sites"][0][3] == []  # the objects check is few_objects' own
    assert st["success"] == {"right": 1, "wrong": 0, "wrong_sites": []}


def test_dominance_finds_the_wrong_pose_no_weaker_than_a_right_refusal():
    m = _mod()
    right = dict(_srec(0, [0.1] * 6, 0.2, "poorly_constrained", occl=0.4), condition="c", run="r")
    weaker = dict(_srec(1, [2.0] * 6, 0.3, "poorly_constrained", occl=0.5), condition="c", run="r")   # wider: no
    stronger = dict(_srec(2, [2.0] * 6, 0.2, "poorly_constrained", occl=0.3, n_objects=12), condition="c", run="r")
    other = dict(_srec(3, [2.0] * 6, 0.1, "misfit_principal_point", occl=0.1), condition="c", run="r")
    (rec, same, anyc), = m.dominance([right], [right, weaker, stronger, other])
    assert rec is right and [r["seed"] for r in same] == [2] and sorted(r["seed"] for r in anyc) == [2, 3]


def test_selection_coverage_per_group():
    m = _mod()
    recs = [dict(_srec(0, [0.1] * 6, 0.1), condition="c", run="r"),                        # |z| 1: covered
            dict(_srec(1, [0.25] * 6, 0.1, "poorly_constrained"), condition="c", run="r"),  # |z| 2.5, right
            dict(_srec(2, [2.0] * 6, 0.1, "poorly_constrained"), condition="c", run="r")]  # wrong: 'all' only
    sel = m.selection(recs)["c"]
    assert sel["success"][:2] == (6, 1.0) and sel["right_refused"][:2] == (6, 0.0) and sel["all"][0] == 18
    assert np.isclose(sel["success"][2], 1 / 1.959964)


def test_committed_realism_records_stops_and_dominance():
    """On the committed realism file: the session-13 final run holds records with parts, none of its
    successes is wrong, and every right refusal of it gets a dominance row."""
    m = _mod()
    runs = m.load_runs()
    if "s13_final" not in runs:
        pytest.skip("the committed realism file no longer holds run s13_final")
    recs = m.distinct_records(runs, ["s13_final"])
    assert len(recs) >= 90
    st = m.stops(recs, (0.5, 0.25, 2.0, 1.2))
    assert st["success"]["wrong"] == 0 and st["success"]["right"] > 50
    rows = m.dominance(recs, m.distinct_records(runs))
    assert len(rows) == sum(not r["success"] and not m.is_wrong(m.error6(r)) for r in recs)
