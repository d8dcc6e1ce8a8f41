"""The detector outline per kind of object (issue 25): a person's box grows (limbs, what is carried)
while a car's shrinks (rounded body, narrower roof), so one set of outline offsets for all objects
cannot represent it. ``boxmodel.outline_kinds`` sorts the matched objects into size kinds from
their 3D boxes (label-free) and ``fit_kind_outline`` fits a width and a height share per kind with
the pose (no vertical shift: within a kind it is the camera's height).
A measured building block (``scripts/outline_bias.py``); of ``calibrate`` only the time-offset
check's box-model test uses it (``misfit._time_box_models``)."""

from __future__ import annotations

import dataclasses

import numpy as np
from test_calib_support import sim_frames
from test_calib_uncertainty import _truth_pairs

import xcalib.calib.boxmodel as boxmodel
from xcalib.calib.boxmodel import OUTLINE_KIND_BOUNDS_M, OUTLINE_KIND_NAMES, fit_kind_outline, outline_kinds
from xcalib.calib.cost import Occlusion
from xcalib.calib.inputs import prepare_frames
from xcalib.calib.pose import Pose
from xcalib.calib.refine import estimate_noise
from xcalib.geometry.boxes import as_box7

SHARES = {"person": (-0.08, -0.02, -0.02), "vehicle": (0.10, 0.08, 0.08), "large": (0.03, 0.03, 0.03)}  # (sides, top, bottom)


def _by_kind(frames):
    """Each 2D box moved in by its kind's shares (kind from its matched 3D box's footprint length)."""
    out = []
    for f in frames:
        b = np.asarray(f.bboxes_2d, dtype=np.float64).copy()
        length = np.full(len(b), 4.0)
        for i, j in np.argwhere(f.match_matrix):
            length[i] = np.max(as_box7(f.bboxes_3d)[j, 3:5])
        sh = np.array([SHARES[OUTLINE_KIND_NAMES[k]] for k in np.digitize(length, OUTLINE_KIND_BOUNDS_M)])
        w, h = b[:, 2] - b[:, 0], b[:, 3] - b[:, 1]
        b += np.column_stack([sh[:, 0] * w, sh[:, 1] * h, -sh[:, 0] * w, -sh[:, 2] * h])
        out.append(dataclasses.replace(f, bboxes_2d=b.astype(np.float32)))
    return out


def _case(frames, T):
    cframes, intr, _ = prepare_frames(frames, frames[0].intrinsics)
    pairs = _truth_pairs(frames, cframes)
    noise = estimate_noise(cframes, pairs, intr, T[:3, :3], T[:3, 3])
    return cframes, pairs, intr, noise, np.arange(sum(len(p) for p in pairs))  # each frame's objects are new


def test_kinds_from_the_3d_box_sizes_and_rare_kinds_joined(monkeypatch):
    frames, T = sim_frames(seed=3, n_frames=6, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    cframes, pairs, _, _, groups = _case(frames, T)
    kinds, names = outline_kinds(cframes, pairs, groups)
    assert names == ["person", "vehicle", "large"] and len(kinds) == len(groups)
    length = np.concatenate([np.max(f.boxes3d[p[:, 1], 3:5], axis=1) for f, p in zip(cframes, pairs)])
    assert np.all(kinds == np.digitize(length, OUTLINE_KIND_BOUNDS_M))
    # with a kind needing 2 objects, all persons as one object join the most frequent kind
    persons = np.where(kinds == 0)[0]
    g = groups.copy()
    g[persons] = g[persons[0]]
    monkeypatch.setattr(boxmodel, "OUTLINE_KIND_MIN_OBJECTS", 2)
    k1, n1 = outline_kinds(cframes, pairs, g)
    assert n1 == ["vehicle", "large"]
    main = int(np.argmax([len(np.unique(g[kinds == k])) for k in (1, 2)]))
    assert np.all(k1[persons] == main) and np.all(k1[kinds == 2] == 1)


def test_per_kind_offsets_recover_each_kinds_outline_where_one_set_cannot():
    frames, T = sim_frames(seed=3, n_frames=6, noise_px=1.0, miss=0.0, false_pos=0.0, extra_3d=0)
    truth = Pose(T[:3, :3], T[:3, 3])
    cframes, pairs, intr, noise, groups = _case(_by_kind(frames), T)
    fit = fit_kind_outline(cframes, pairs, intr, truth, noise, 2.0, Occlusion(), groups)
    assert fit["kinds"] == ["person", "vehicle", "large"]
    for k in ("person", "vehicle"):
        got = fit["offsets"][k]
        assert abs(got["sides"] - SHARES[k][0]) < 0.03 and abs(got["height"] - SHARES[k][1]) < 0.04, (k, got)
    assert fit["cost"]["kinds"] < fit["cost"]["common"] < fit["cost"]["plain"]
    assert fit["pose"].error(truth)[0] < 0.1 and fit["pose"].error(truth)[1] < 0.1
    # exact boxes: every kind's offsets stay near 0
    clean = fit_kind_outline(*_case(frames, T)[:3], truth, noise, 2.0, Occlusion(), groups)
    assert max(abs(v) for o in clean["offsets"].values() for v in o.values()) < 0.02
