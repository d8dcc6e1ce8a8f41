"""The change test's statistics: a threshold from a false-alarm rate and the change it can detect.

Every decision tests a handful of 6-vectors ``d`` (a pose change: rotation vector in radians about
the camera axes, translation in metres along them) against their covariance ``C`` with the
statistic ``s = d^T C^-1 d`` (chi-square, 6 degrees of freedom, when nothing changed). A decision
runs ``n_tests`` such tests every ``stride`` frames; the threshold is set by a union (Bonferroni)
bound so that the expected number of false alarms per frame stays below ``rate``: each test
gets ``rate * stride / n_tests``. Overlapping windows make successive decisions correlated, so the
real rate is lower than the bound (the benchmark measures it).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.stats import chi2, ncx2

__all__ = ["threshold", "scan_threshold", "detectable_lambda", "detectable_change", "chi2_stat", "select_model", "pure_models",
           "sparse_step", "variance_upper"]

DOF = 6


def threshold(rate_per_frame: float, stride: int, n_tests: int) -> float:
    """Chi-square (6 dof) threshold that keeps false alarms below ``rate_per_frame``."""
    if not 0.0 < rate_per_frame < 1.0:
        raise ValueError(f"false_alarm_rate must be in (0, 1) per frame, got {rate_per_frame}")
    p = min(0.5, rate_per_frame * max(int(stride), 1) / max(int(n_tests), 1))
    return float(chi2.isf(p, DOF))


#: simulated decisions behind ``scan_threshold`` (a fixed seed: the same threshold every run)
SCAN_DECISIONS = 1_000_000


def scan_threshold(rate_per_frame: float, stride: int, n_tests: int, lengths: tuple[int, ...],
                   history: int) -> float:
    """Chi-square (6 dof) threshold of a change-point scan: each decision tests the last L frames
    against the frames before them (up to ``history`` in all) for every L in ``lengths`` and
    takes the largest statistic. Those tests overlap (a 45- and a 50-frame segment share 45
    frames), so a union bound over them would be far too strict; the threshold is instead the
    quantile of the largest statistic's null distribution, simulated (``SCAN_DECISIONS``
    decisions, fixed seed) for independent frames of equal information: there the statistics
    depend only on the lengths. The scan gets the share of the decision's false-alarm budget
    ``rate * stride`` that its ``n_tests - 1`` tests would get under the union bound (the last
    test, the offset from the calibration, keeps its own share), so it is comparable with
    ``threshold`` for the fixed windows (for 20 / 40 / 80 frames the simulated rate at
    ``threshold`` is 0.91 of the bound's)."""
    if not 0.0 < rate_per_frame < 1.0:
        raise ValueError(f"false_alarm_rate must be in (0, 1) per frame, got {rate_per_frame}")
    p = min(0.5, rate_per_frame * max(int(stride), 1) * (max(int(n_tests), 2) - 1) / max(int(n_tests), 2))
    return _scan_quantile(tuple(sorted(int(v) for v in lengths)), int(history), float(p))


@lru_cache(maxsize=16)
def _scan_quantile(lengths: tuple[int, ...], history: int, p: float) -> float:
    rng = np.random.default_rng(20261128)
    L = np.asarray(lengths)
    Lmax, step = int(L.max()), int(np.gcd.reduce(L))
    if history <= Lmax:
        raise ValueError(f"scan_threshold: history ({history}) must exceed the longest segment ({Lmax})")
    best, chunk = [], 20_000
    for _ in range(SCAN_DECISIONS // chunk):
        pre = rng.standard_normal((chunk, 6)) * np.sqrt(history - Lmax)  # the frames before the last Lmax
        blocks = rng.standard_normal((chunk, Lmax // step, 6)) * np.sqrt(step)  # the last Lmax, newest first
        tail = np.cumsum(blocks, 1)[:, L // step - 1]  # [k, len(L), 6]: sums of the last L frames
        tot = (pre + tail[:, -1])[:, None]
        d = tail / L[None, :, None] - (tot - tail) / (history - L)[None, :, None]
        s = (d * d).sum(2) / (1.0 / L + 1.0 / (history - L))[None]
        best.append(s.max(1))
    return float(np.quantile(np.concatenate(best), 1.0 - p))


def detectable_lambda(h: float, power: float = 0.95) -> float:
    """Non-centrality a change needs to cross the threshold ``h`` with probability ``power``."""
    lo, hi = 0.0, 10.0 * h + 100.0
    for _ in range(60):  # bisection: ncx2.sf grows with the non-centrality
        mid = 0.5 * (lo + hi)
        if ncx2.sf(h, DOF, mid) < power:
            lo = mid
        else:
            hi = mid
    return hi


def detectable_change(cov: np.ndarray, lam: float) -> np.ndarray:
    """Per axis, the smallest change along that axis alone detected with non-centrality ``lam``:
    ``sqrt(lam / (C^-1)_aa)`` (6-vector: rad, rad, rad, m, m, m; inf where C is singular)."""
    try:
        info = np.linalg.inv(cov)
    except np.linalg.LinAlgError:
        return np.full(DOF, np.inf)
    d = np.diag(info)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(d > 0, np.sqrt(lam / d), np.inf)


def chi2_stat(d: np.ndarray, cov: np.ndarray) -> float:
    """``d^T C^-1 d`` (inf where C is singular and d is not zero)."""
    try:
        return float(d @ np.linalg.solve(cov, d))
    except np.linalg.LinAlgError:
        return float("inf") if np.any(d != 0) else 0.0


MODEL_LEVEL = 0.01  # a nested model (rotation only / translation only) is kept unless rejected at this level


def pure_models(d: np.ndarray, cov: np.ndarray) -> list[tuple[float, np.ndarray, np.ndarray, str]]:
    """The pure models of a change ``d`` (6-vector, rad / m) with covariance ``cov`` that the data
    do not reject at MODEL_LEVEL: a pure rotation, a pure translation (each: the constrained
    generalised least squares estimate, kept when its misfit ``(d - E a)^T C^-1 (d - E a)`` is
    below the chi-square(3) quantile), best first: (misfit, estimate [6], covariance [6,6], name)."""
    try:
        info = np.linalg.inv(cov)
    except np.linalg.LinAlgError:
        return []
    limit = float(chi2.isf(MODEL_LEVEL, 3))
    kept = []
    for name, sl in (("rotation", slice(0, 3)), ("translation", slice(3, 6))):
        E = np.zeros((6, 3))
        E[sl] = np.eye(3)
        fit = _constrained_fit(d, info, E)
        if fit is not None and fit[0] < limit:
            misfit, a, ca = fit
            kept.append((misfit, E @ a, E @ ca @ E.T, name))
    return sorted(kept, key=lambda q: q[0])


def _constrained_fit(d: np.ndarray, info: np.ndarray, E: np.ndarray):
    """The generalised least squares fit of ``d`` (information ``info``) restricted to the columns of
    ``E`` (d ~ E a): (misfit, a, cov(a)), or None when the restricted information is singular."""
    try:
        ca = np.linalg.inv(E.T @ info @ E)
    except np.linalg.LinAlgError:
        return None
    a = ca @ E.T @ info @ d
    res = d - E @ a
    return float(res @ info @ res), a, ca


def select_model(d: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, str]:
    """The simplest model of a change ``d`` (6-vector, rad / m) with covariance ``cov`` that the data
    do not reject (``pure_models``: the better of a pure rotation and a pure translation when both
    are kept) or both. Returns (estimate [6], covariance [6,6], "rotation" | "translation" |
    "rotation+translation")."""
    kept = pure_models(d, cov)
    if not kept:
        return d, cov, "rotation+translation"
    return kept[0][1], kept[0][2], kept[0][3]


def sparse_step(d: np.ndarray, cov: np.ndarray, axes, level: float = MODEL_LEVEL) -> tuple[np.ndarray, tuple[int, ...]]:
    """The change ``d`` (6-vector, rad / m; covariance ``cov``) on the fewest of ``axes`` (indices
    0-5: the axes of the model ``pure_models`` chose) that the data do not reject at ``level``:
    every subset S of ``axes`` gets its constrained generalised least squares estimate, kept when
    its misfit is below the chi-square(6 - |S|) quantile; the smallest kept subset wins (ties: the
    smaller misfit); the whole of ``axes`` when none smaller is kept. An axis left out is one the
    window cannot tell from no change (a 10 cm shift along x does not also report the view axis's
    2-3 cm of noise as a shift along z). Returns (estimate [6], the axes kept)."""
    from itertools import combinations

    axes = tuple(int(a) for a in axes)
    try:
        info = np.linalg.inv(cov)
    except np.linalg.LinAlgError:
        return np.asarray(d, dtype=np.float64), axes
    best = None
    for k in range(1, len(axes) + 1):
        for S in combinations(axes, k):
            E = np.zeros((DOF, k))
            E[list(S), range(k)] = 1.0
            fit = _constrained_fit(d, info, E)
            if fit is None:
                continue
            misfit, a, _ = fit
            if (k == len(axes) or misfit < float(chi2.isf(level, DOF - k))) and (best is None or misfit < best[0]):
                best = (misfit, E @ a, S)
        if best is not None:
            return best[1], best[2]
    return np.asarray(d, dtype=np.float64), axes


def variance_upper(sum_sq: np.ndarray, m: int, confidence: float) -> np.ndarray:
    """Upper ``confidence`` bound of a variance from ``m`` squared standardised samples summing to
    ``sum_sq`` (per axis): ``sum_sq / chi2_m quantile at 1 - confidence`` (the samples taken as
    independent normal)."""
    return np.asarray(sum_sq, dtype=np.float64) / float(chi2.ppf(1.0 - confidence, max(int(m), 1)))
