"""Coverage of 95 % bounds built on a cluster-robust (CR2) covariance with few clusters (issue 25, session 10).

A linear model with ``G`` clusters (objects) of unequal sizes and leverage, every cluster's rows
sharing one error (a random intercept) beside independent noise, 6 parameters in two blocks of 3
(rotation, translation); the estimate is least squares, its covariance the CR2 sandwich of
``xcalib.calib.uncertainty.cr2_covariance`` with Bell-McCaffrey degrees of freedom, exactly as the
calibration computes it from the objects' scores and informations. Per block, the share of draws
whose error norm lies within each bound (0.95 = right):

* ``old``: each axis's CR2 sigma stretched by t(0.975, nu_k) / 1.96, the stretched sigmas in the
  chi-square bound (``bound95(sd)``; what the decision uses until session 10);
* ``new``: the raw CR2 block covariance (correlations included) in the F bound with the
  Satterthwaite degrees of freedom of its trace from the cross-axis dof matrix
  (``bound95(cov=..., dof=bound_dof(...))``);
* ``new_diag``: the same without the correlations; ``rho1`` / ``rho0``: the trace's dofs from the
  per-axis dofs taken as fully correlated / independent (what a record without the cross-axis
  matrix allows);
* ``chi2raw``: the raw sigmas in the chi-square bound (no small-sample correction).

``axis``: the per-axis 2-sigma (stretched) coverage. Settings: ``shared`` -- every cluster informs
every axis (mixed regressors); ``separate`` -- each axis is informed by its own clusters only (the
axes' variance estimates independent, where stretching each axis and then adding them is widest).

    PYTHONPATH=src python scripts/bound_sim.py [--reps 2000]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

SETTINGS = [  # (G, leverage log-sd, regressor mixing, cluster sizes low-high, design)
    (4, 0.0, 0.0, (5, 5), "shared"), (5, 0.8, 0.5, (1, 12), "shared"), (6, 0.8, 0.5, (1, 12), "shared"),
    (8, 0.8, 0.5, (1, 12), "shared"), (8, 1.2, 1.0, (1, 20), "shared"), (12, 0.8, 0.5, (1, 12), "shared"),
    (20, 0.8, 0.5, (1, 12), "shared"), (6, 0.0, 1.0, (3, 3), "shared"),
    (12, 0.0, 0.0, (4, 4), "separate"), (18, 0.8, 0.0, (1, 12), "separate"),
]
KINDS = ("old", "new", "new_diag", "rho1", "rho0", "chi2raw")


def _design(rng, G, lev_sd, mix, sizes, design):
    n = rng.integers(sizes[0], sizes[1] + 1, G)
    lev = np.exp(lev_sd * rng.normal(size=G))
    Xs = []
    for c in range(G):
        if design == "separate":  # cluster c informs axis c % 3 of each block (plus a little of all)
            base = np.zeros(6)
            base[[c % 3, 3 + c % 3]] = lev[c]
            Xs.append(base + 0.05 * rng.normal(size=(n[c], 6)))
        else:
            base = rng.normal(size=6) @ mix * lev[c]
            Xs.append(base + 0.3 * lev[c] * rng.normal(size=(n[c], 6)) @ mix)
    return Xs


def run(G, lev_sd, corr, sizes, design, reps, seed, tau=1.0, sig=0.5):
    """Per-block coverage of each bound kind, the per-axis 2-sigma coverage, the median dof."""
    from scipy.special import stdtrit

    from xcalib.calib.diagnostics import bound95
    from xcalib.calib.uncertainty import bound_dof, cr2_covariance

    rng = np.random.default_rng(seed)
    mix = np.eye(6) + corr * rng.normal(size=(6, 6)) / np.sqrt(6)
    hits = dict.fromkeys(KINDS, 0.0)
    axis, nus, m = [], [], 0
    for _ in range(reps):
        Xs = _design(rng, G, lev_sd, mix, sizes, design)
        es = [tau * rng.normal() + sig * rng.normal(size=len(x)) for x in Xs]
        X, y = np.concatenate(Xs), np.concatenate(es)
        A = np.linalg.inv(X.T @ X)
        b = A @ X.T @ y
        r = y - X @ b
        off = np.cumsum([0] + [len(x) for x in Xs])
        g = np.stack([Xs[c].T @ r[off[c]:off[c + 1]] for c in range(G)])
        M = np.stack([x.T @ x for x in Xs])
        S = np.zeros((6, 6))
        out = cr2_covariance(A, g, M, cross_out=S)
        if out is None:
            continue
        cov, nu = out
        m += 1
        nus.append(nu)
        sd = np.sqrt(np.diag(cov))
        st = sd * stdtrit(np.clip(nu, 1, None), 0.975) / 1.959964
        axis.append(np.abs(b) <= 1.959964 * st)
        for blk in (slice(0, 3), slice(3, 6)):
            e, v, nb = np.linalg.norm(b[blk]), np.diag(cov)[blk], nu[blk]
            dof = bound_dof(v, v, S[blk, blk])
            rho1 = bound_dof(v, v, 1.0 / np.sqrt(np.outer(nb, nb)))
            rho0 = bound_dof(v, v, np.diag(1.0 / nb))
            for k, bound in (("old", bound95(st[blk])), ("new", bound95(None, cov=cov[blk, blk], dof=dof)),
                             ("new_diag", bound95(sd[blk], dof=dof)), ("rho1", bound95(sd[blk], dof=rho1)),
                             ("rho0", bound95(sd[blk], dof=rho0)), ("chi2raw", bound95(sd[blk]))):
                hits[k] += 0.5 * (e <= bound)
    return {k: v / max(m, 1) for k, v in hits.items()}, float(np.mean(axis)), float(np.median(nus)), m


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=2000)
    args = ap.parse_args(argv)
    print(f"per-block coverage of the 95 % bounds, {args.reps} draws per setting (binomial sd ~"
          f"{np.sqrt(0.05 * 0.95 / args.reps / 2):.3f} per block)")
    for i, (G, lev, corr, sizes, design) in enumerate(SETTINGS):
        cov, ax, nu, m = run(G, lev, corr, sizes, design, args.reps, 7 + i)
        print(f"{design:8s} G={G:2d} leverage sd {lev} sizes {sizes[0]}-{sizes[1]}: " + " ".join(f"{k} {v:.3f}" for k, v in cov.items())
              + f" | axis 2sd {ax:.3f} | median nu {nu:.1f} | n={m}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
