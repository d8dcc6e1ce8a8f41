"""The ``uncertain`` refusal names the part(s) of its 95 % bound that make most of it, in words a user
can act on (session 15, U; the session 14 review's finding: a pose refused because the focal length's
choice widened the sigma was told to "add recordings with other objects")."""

from __future__ import annotations

import numpy as np

from xcalib.calib.config import CalibConfig
from xcalib.calib.decision import Evidence, bound_parts, verdict
from xcalib.calib.diagnostics import UncertaintyParts


def _ev(parts, total):
    total = np.asarray(total, dtype=np.float64)
    return Evidence(n_pairs=200, n_2d=240, most_per_frame=10, places=10, places_off_line=5, halves_available=True,
                    best_score=50.0, runner_up_score=0.0, rot_sd=np.full(3, 0.05), tr_sd=np.full(3, 0.03),
                    rot_sd_total=total[:3], tr_sd_total=total[3:], n_objects=30, parts=parts)


def _parts(focal=None, jac=0.02):
    small = [jac] * 3 + [0.02] * 3
    return UncertaintyParts(jacobian=small, clusters=small, focal_box_model=focal)


def test_a_bound_the_focal_choice_widens_is_refused_naming_the_focal_length():
    focal = [0.05, 0.05, 0.05, 0.05, 0.05, 1.5]  # the move to the fitted focal length: along the view axis
    total = np.sqrt(np.square(focal) + 0.02 ** 2)
    ref = verdict(_ev(_parts(focal), total), CalibConfig())
    assert ref is not None and ref.code == "uncertain"
    assert "focal length's choice" in ref.message and "--intrinsics" in ref.message, ref.message
    assert "add recordings with other objects" not in ref.message  # not the advice that cannot help here
    assert bound_parts(_ev(_parts(focal), total), CalibConfig())[0][0] == "focal_choice"


def test_a_bound_the_objects_scatter_makes_keeps_the_objects_advice():
    jac = 0.9
    total = np.array([jac] * 3 + [0.3] * 3)
    ref = verdict(_ev(_parts(None, jac), total), CalibConfig())
    assert ref is not None and ref.code == "uncertain"
    assert "scatter between the distinct objects" in ref.message and "other objects" in ref.message
    # without stored parts: the message as before (nothing named)
    bare = verdict(_ev(None, np.array([0.8] * 3 + [0.3] * 3)), CalibConfig())
    assert bare.code == "uncertain" and "most of it" not in bare.message


def test_a_part_far_below_the_bound_is_not_named_as_most_of_it():
    """Session 15 review (R): with ``uncertainty="frames"`` (no objects' part) the bound is the frames' own sigma;
    the largest stored part (an outline shift of 0.00 deg / 0.05 m against a bound of 0.61 deg) was named as "most
    of it" and its advice replaced the general one. A part is named only where it makes at least half the bound."""
    tiny = [0.01] * 3 + [0.01] * 3
    parts = UncertaintyParts(jacobian=tiny, focal_box_model=[0.02] * 3 + [0.01] * 3)
    total = np.array([0.9] * 3 + [0.3] * 3)
    assert bound_parts(_ev(parts, total), CalibConfig()) == []
    ref = verdict(_ev(parts, total), CalibConfig())
    assert ref.code == "uncertain" and "most of it" not in ref.message and "focal length" not in ref.message
    assert "other objects" in ref.message  # the general advice stays
