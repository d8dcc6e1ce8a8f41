"""The object-clustered (CR2) part's Student's t stretch counts only beyond the model sigma (issues 25 / 26, session 13)."""

import numpy as np
from scipy.special import stdtrit

from xcalib.calib.uncertainty import clustered_part

Z = 1.959964


def _stretched(raw, dof):
    return raw * stdtrit(np.asarray(dof, dtype=np.float64), 0.975) / Z


def test_clustered_part_keeps_the_whole_stretch_without_a_model_and_none_at_the_model():
    dof = np.array([2.0, 3.0, 5.0, 8.0, 20.0, 3.5])
    raw = np.array([0.1, 0.2, 0.3, 0.05, 0.02, 0.4])
    clus = _stretched(raw, dof)
    # no model sigma: the CR2 estimate is all there is, the whole stretch stays
    assert np.allclose(clustered_part(clus, dof, np.zeros(6)), clus, rtol=1e-12)
    # the model sigma equal to the unstretched CR2: nothing beyond it to stretch
    assert np.allclose(clustered_part(clus, dof, raw), raw, rtol=1e-12)
    # between: above the raw CR2, below the stretched one, and nearer the stretched one the smaller the model
    half = clustered_part(clus, dof, 0.5 * raw)
    tenth = clustered_part(clus, dof, 0.1 * raw)
    assert np.all(raw < half) and np.all(half < tenth) and np.all(tenth < clus)
    # the reported sigma (the max with the model) never widens
    for model in (0.0, 0.3, 0.9, 1.0, 1.5, 4.0):
        assert np.all(np.fmax(clustered_part(clus, dof, model * raw), model * raw)
                      <= np.fmax(clus, model * raw) * (1 + 1e-12))
    # None / no dofs: as given
    assert clustered_part(None, dof, raw) is None
    assert clustered_part(clus, None, raw) is clus


def test_clustered_part_covers_95_percent_where_the_max_with_the_whole_stretch_covers_98():
    """Seeded simulation of the combination: errors N(0, V), the model variance F known, the CR2 variance
    V chi2_nu / nu at nu = 3. With no clustering beyond the model (V = F) the max with the whole stretch
    covers ~98 % at 1.96 sigma; the stretch counted beyond the model ~96.7 %; with much clustering (V = 4 F,
    10 F) both stay near 95 % (the whole-stretch max can only be wider)."""
    rng = np.random.default_rng(7)
    nu, n = 3.0, 200_000
    k = stdtrit(nu, 0.975) / Z
    cover = {}
    for r in (1.0, 4.0, 10.0):
        v = r * rng.chisquare(nu, n) / nu
        e = np.abs(rng.normal(0.0, np.sqrt(r), n))
        full = np.fmax(1.0, k * np.sqrt(v))
        new = np.fmax(1.0, clustered_part(k * np.sqrt(v), np.full(n, nu), np.ones(n)))
        cover[r] = (float(np.mean(e <= Z * full)), float(np.mean(e <= Z * new)))
    assert cover[1.0][0] > 0.978 and 0.955 < cover[1.0][1] < 0.975
    for r in (4.0, 10.0):
        assert 0.91 < cover[r][1] <= cover[r][0] + 1e-12 and cover[r][0] > 0.945
