"""The information a window of synthetic frames holds about each axis of a pose change, under the
generator's own noise (``xcalib.data.synth``: 2D box coordinates iid ``box_noise_px``; 3D centre
iid 0.1 m per LiDAR axis, size 3 % per axis, yaw 2 deg -- per frame and box), against what the
monitor's test makes of it (``bench_monitor.py --part information``).

Cramer-Rao bound: per matched pair (matched at the true pose) the box-edge residual is linearised,
``r = J x + N e + n`` (``J`` [4,6] the edges' pixel Jacobian in the pose change, ``N`` [4,7] in the
box's centre, size and yaw errors ``e``, ``n`` the 2D noise), ``Cov = s2d^2 I + N diag(sig^2) N^T``
(the four edges' correlation kept); the information is ``sum J^T Cov^-1 J``. Occluded and
truncated boxes count as exact and the noise as Gaussian, so the bound is optimistic (the
information is an upper bound). From it: the 1-sigma of each axis over a window (the other five
profiled out) and the power of the monitor's 6-dof two-sample test (its threshold, a
``window``-frame segment against a ``ref``-frame reference) for a step on one axis.

Monitor: on a drift-free stream, every 20 frames the test the decisions run (the last 40 frames
against the 250 before them): the empirical spread of the difference ``d`` against the
covariance the test uses (mean of ``d^T C^-1 d``: 6 when the covariance is right); per window
length (20 / 40 / 80 frames against 250) the same for the monitor's covariance and for the
matched pairs' sandwich, which is right where the frames' errors are independent and too small
where they are not (an object occluded alike frame after frame): the figures that say why the
monitor's covariance is too large on some axes and why the sandwich cannot replace it.
"""

from __future__ import annotations

import numpy as np

SIG_NUISANCE = np.array([0.1, 0.1, 0.1, 0.03, 0.03, 0.03, np.radians(2.0)])  # the generator's 3D errors
TARGET = np.array([np.radians(0.25)] * 3 + [0.10] * 3)
AXES = ("rx", "ry", "rz", "tx", "ty", "tz")


def frame_information(cm, frames, s2d: float, sig: np.ndarray = SIG_NUISANCE) -> np.ndarray:
    """[n,6,6]: each frame's information about the pose change (rad / m) at the calibration
    (``sig``: the 3D boxes' 1-sigma: centre per axis m [3], relative size per axis [3], yaw rad)."""
    from xcalib.calib.boxproj import project_rects
    from xcalib.calib.refine import edge_term, match_frame
    from xcalib.monitor.core import _EPS, _perturbations

    pose = cm.pose0
    Rs, ts = _perturbations(pose)
    d = 1e-4
    out = []
    for f in frames:
        cf = cm._prepare(f)
        pairs, _, _ = match_frame(cf, cm.intr, pose.R, pose.t, gate_iou=0.2, gate_dist=0.5)
        info = np.zeros((6, 6))
        if len(pairs):
            term = edge_term([cf], [pairs], cm.intr, pose, cm.noise, None)
            c = term.outlines

            def rect(cc):
                return project_rects(cc, pose.R, pose.t, cm.intr, term.size)[0]

            rects, _ = project_rects(c, Rs, ts, cm.intr, term.size)
            J = np.transpose((rects[1::2] - rects[2::2]) / (2 * _EPS), (1, 2, 0))  # [m,4,6]
            m0 = c.mean(1, keepdims=True)
            dev = c - m0
            nuis = []
            for k in range(3):  # centre along the LiDAR axes
                e = np.zeros(3)
                e[k] = d
                nuis.append((rect(c + e) - rect(c - e)) / (2 * d))
            _, V = np.linalg.eigh(np.einsum("msi,msj->mij", dev, dev))  # the box's axes
            for k in range(3):  # relative size along each
                a = V[:, :, k]
                proj = np.einsum("msi,mi->ms", dev, a)[..., None] * a[:, None, :]
                nuis.append((rect(c + d * proj) - rect(c - d * proj)) / (2 * d))

            def turned(th):
                cs, sn = np.cos(th), np.sin(th)
                return m0 + np.stack([cs * dev[..., 0] - sn * dev[..., 1], sn * dev[..., 0] + cs * dev[..., 1],
                                      dev[..., 2]], -1)

            nuis.append((rect(turned(d)) - rect(turned(-d))) / (2 * d))
            N = np.stack(nuis, -1)  # [m,4,7]
            for p in range(len(pairs)):
                rows = np.any(J[p] != 0, axis=1) & np.all(np.isfinite(J[p]), 1) & np.all(np.isfinite(N[p]), 1)
                if rows.any():
                    Jp, Np = J[p][rows], N[p][rows]
                    Cp = s2d ** 2 * np.eye(int(rows.sum())) + Np @ np.diag(np.asarray(sig) ** 2) @ Np.T
                    info += Jp.T @ np.linalg.solve(Cp, Jp)
        out.append(info)
    return np.array(out)


def bound_rows(infos: np.ndarray, h: float, ref: int = 250, windows=(40, 50)) -> dict:
    """Per window length: the median 1-sigma per axis (deg / m, others profiled) and, per axis, the
    mean power of the 6-dof test (threshold ``h``) for the target step on that axis alone."""
    from scipy.stats import ncx2

    out = {}
    n = len(infos)
    for L in windows:
        sds, pw = [], []
        for a in range(0, n - L - ref + 1, 25):
            Ib, Ia = infos[a:a + ref].sum(0), infos[a + ref:a + ref + L].sum(0)
            Cd_inv = np.linalg.inv(np.linalg.inv(Ia) + np.linalg.inv(Ib))
            sds.append(np.sqrt(np.diag(np.linalg.inv(Ia))))
            pw.append([ncx2.sf(h, 6, TARGET[k] ** 2 * Cd_inv[k, k]) for k in range(6)])
        sd = np.median(sds, 0)
        out[f"window_{L}"] = {"sigma_per_axis": [*np.degrees(sd[:3]).tolist(), *sd[3:].tolist()],
                              "power_6dof_target_step": dict(zip(AXES, np.mean(pw, 0).tolist())),
                              "placements": len(pw)}
    return out


def sequential_rows(infos: np.ndarray, rate: float, stride: int, ref: int = 250, targets=((5, 0.10, 50), (5, 0.20, 20)),
                    scan: int = 80) -> dict:
    """Does a sequential change-point statistic reach a step sooner than the fixed windows at the same
    false-alarm rate? Per target (axis, step, within W frames), the power of the last decision within
    W frames of the change (the change D frames back, D uniform over the decision phases in
    (W - stride, W]) under this information (``infos``; the best single test's power, a lower bound
    of the decision's): "fixed" (the monitor's windows 20 / 40 / 80
    and the calibration test: 4 tests a decision), "fixed_plus_target" (and a window of W - stride
    frames: 5 tests), "glr_scan" (the two-sample statistic at every change point within the last
    ``scan`` frames: the segment since the change exactly, ``scan`` + 1 tests a decision,
    Bonferroni as the monitor's threshold). Segments against ``ref`` frames before them."""
    from scipy.stats import chi2, ncx2

    n = len(infos)
    out = {}
    for axis, size, W in targets:
        rows = {"fixed": [], "fixed_plus_target": [], "glr_scan": []}
        h = {"fixed": chi2.isf(rate * stride / 4, 6), "fixed_plus_target": chi2.isf(rate * stride / 5, 6),
             "glr_scan": chi2.isf(rate * stride / (scan + 1), 6)}
        for a in range(80, n - ref - W + 1, 25):
            for D in range(W - stride + 1, W + 1):
                end = a + ref + D  # the decision: the change D frames back

                def power(L, hh):
                    """The test of the last L frames (the last D of them changed) against the ref frames before them."""
                    Ia, Ip = infos[end - L:end].sum(0), infos[end - min(L, D):end].sum(0)
                    Ibb = infos[end - L - ref:end - L].sum(0)
                    d = np.linalg.solve(Ia, Ip[:, axis]) * size  # a mixed segment sees part of the step
                    lam = float(d @ np.linalg.solve(np.linalg.inv(Ia) + np.linalg.inv(Ibb), d))
                    return ncx2.sf(hh, 6, lam)

                rows["fixed"].append(max(power(L, h["fixed"]) for L in (20, 40, 80)))
                rows["fixed_plus_target"].append(max(power(L, h["fixed_plus_target"]) for L in (20, 40, 80, W - stride)))
                rows["glr_scan"].append(power(D, h["glr_scan"]))
        out[f"{AXES[axis]}_{size:g}_within_{W}"] = {k: float(np.mean(v)) for k, v in rows.items()} | \
            {f"threshold_{k}": float(v) for k, v in h.items()}
    return out


def _pairs_sandwich(recs, a: int, b: int, H: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The covariance of a segment's estimate ``x`` (frames [a, b), information ``H``) from the spread
    of its matched pairs' own scores (each pair's four edges one cluster, its score at ``x``):
    ``H^-1 (sum s s^T) H^-1 n / (n - 6)``. Right when the frames' errors are independent."""
    M, n = np.zeros((6, 6)), 0
    for q in recs[a:b]:
        if q.obj_g is None or not len(q.obj_g):
            continue
        s = q.obj_g + np.einsum("kij,j->ki", q.obj_H, x)
        M += s.T @ s
        n += len(s)
    Hi = np.linalg.inv(H)
    return Hi @ M @ Hi * n / max(n - 6, 1)


def _spread(D: list, C: list, S: list, lam: float) -> dict:
    from xcalib.monitor import stats

    D, C = np.array(D), np.array(C)
    emp, nom = D.std(0), np.sqrt(np.median(np.diagonal(C, axis1=1, axis2=2), 0))
    return {"tests": len(D), "mean_chi2_6dof": float(np.mean(S)), "max_chi2_6dof": float(np.max(S)),
            "share_above_chi2_6dof_1pct": float(np.mean(np.array(S) > 16.81)),
            "empirical_sd_per_axis": [*np.degrees(emp[:3]).tolist(), *emp[3:].tolist()],
            "stated_sd_per_axis": [*np.degrees(nom[:3]).tolist(), *nom[3:].tolist()],
            "stated_over_empirical_variance": dict(zip(AXES, (nom ** 2 / emp ** 2).tolist())),
            "detectable_tz_median_m": float(np.median([stats.detectable_change(c, lam)[5] for c in C]))}


def monitor_spread(cal, frames, every: int = 20, L: int = 40, ref: int = 250, windows=(20, 40, 80)) -> dict:
    """The monitor's own test on a drift-free stream: empirical vs stated spread of d (the last
    ``L`` frames against the ``ref`` before them, every ``every`` frames), and, per window length
    in ``windows`` (``by_window``), the same for the monitor's covariance ("model": the noise model
    scaled by the weighted residuals' variance, times the adjacent-window inflation) and for the
    pairs' sandwich (``_pairs_sandwich``, times the same inflation): which one is right, on which axis."""
    from xcalib.monitor import Monitor, MonitorConfig, stats
    from xcalib.monitor.core import _Sums

    Lmax = max(max(windows), L)
    mon = Monitor(cal, MonitorConfig(latch=False, history=max(len(frames), 600), false_alarm_rate=1e-12))
    cm = next(iter(mon.cameras.values()))
    D, C, S = [], [], []
    by = {(w, kind): ([], [], []) for w in windows for kind in ("model", "pairs")}
    phis = []
    for i, f in enumerate(frames):
        mon.update(f)
        if i + 1 >= Lmax + ref and (i + 1 - Lmax - ref) % every == 0:
            recs = list(cm.recs)[-(Lmax + ref):]
            sums = _Sums(recs)
            m, phi = len(recs), cm.inflation
            phis.append(phi)
            fa, fb = sums.fit(m - L, m, phi), sums.fit(m - L - ref, m - L, phi)
            if fa is not None and fb is not None:
                D.append(fa.x - fb.x)
                C.append(fa.cov + fb.cov)
                S.append(stats.chi2_stat(D[-1], C[-1]))
            for w in windows:
                a0, a1, b1 = m - w - ref, m - w, m
                fa, fb = sums.fit(a1, b1, phi), sums.fit(a0, a1, phi)
                if fa is None or fb is None:
                    continue
                d = fa.x - fb.x
                cp = phi * (_pairs_sandwich(recs, a1, b1, sums.H[b1] - sums.H[a1], fa.x)
                            + _pairs_sandwich(recs, a0, a1, sums.H[a1] - sums.H[a0], fb.x))
                for kind, cov in (("model", fa.cov + fb.cov), ("pairs", cp)):
                    q = by[(w, kind)]
                    q[0].append(d)
                    q[1].append(cov)
                    q[2].append(stats.chi2_stat(d, cov))
    out = _spread(D, C, S, cm.lam)
    out["inflation_median"] = float(np.median(phis)) if phis else None
    out["by_window"] = {f"{kind}_window_{w}": _spread(*by[(w, kind)], cm.lam) for (w, kind) in by if by[(w, kind)][0]}
    return out


def efficient_rows(infos: np.ndarray, rate: float, stride: int, ref: int = 250,
                   targets=((5, 0.10, 50), (5, 0.20, 20)), every: int = 10) -> dict:
    """Settle whether a step can be seen at all: per target (axis, step, within W frames) and
    placement (every ``every`` frames), the step's information over exactly the W frames after it
    against the ``ref`` frames before it (the change point known: more than any monitor has),
    ``Cd = I_after^-1 + I_before^-1``:

    * ``crb_sigma``: the Cramer-Rao 1-sigma of the axis over the W frames alone (other five
      axes free) and of the two-sample difference (``two_sample_sigma``), in m / deg;
    * ``power_6dof``: an efficient test that does not know the direction (``d^T Cd^-1 d``, 6 dof;
      non-centrality ``s^2 (Cd^-1)_kk``), one test every ``stride`` frames at the false-alarm
      rate (``chi2.isf(rate * stride, 6)``: a single test a decision, less than the monitor's 4);
    * ``power_axes_1dof``: six 1-dof tests, one per axis, others free (``d_k^2 / Cd_kk``,
      threshold ``chi2.isf(rate * stride / 6, 1)``), for single-axis steps;
    * ``power_oracle_1dof``: the test that knows the step's direction and time (1 dof,
      non-centrality ``s^2 (Cd^-1)_kk``, threshold ``chi2.isf(rate * stride, 1)``): no test
      at this false-alarm rate can do better with these observations (an upper bound, since the
      information itself is an upper bound).
    Means over placements, and the share of placements whose oracle power reaches 0.95."""
    from scipy.stats import chi2, ncx2, norm

    n = len(infos)
    alpha = rate * stride
    h6, h1, hax = chi2.isf(alpha, 6), chi2.isf(alpha, 1), chi2.isf(alpha / 6, 1)
    out = {}
    for axis, size, W in targets:
        rows = {k: [] for k in ("crb", "two", "p6", "pax", "por")}
        for a in range(0, n - ref - W + 1, every):
            Ib, Ia = infos[a:a + ref].sum(0), infos[a + ref:a + ref + W].sum(0)
            try:
                Cd = np.linalg.inv(Ia) + np.linalg.inv(Ib)
                Ci = np.linalg.inv(Cd)
                crb = np.sqrt(np.linalg.inv(Ia)[axis, axis])
            except np.linalg.LinAlgError:
                continue
            lam_c = size ** 2 * Ci[axis, axis]
            z_m = size / np.sqrt(Cd[axis, axis])
            rows["crb"].append(crb)
            rows["two"].append(np.sqrt(Cd[axis, axis]))
            rows["p6"].append(ncx2.sf(h6, 6, lam_c))
            rows["pax"].append(norm.sf(np.sqrt(hax) - z_m) + norm.cdf(-np.sqrt(hax) - z_m))
            rows["por"].append(norm.sf(np.sqrt(h1) - np.sqrt(lam_c)) + norm.cdf(-np.sqrt(h1) - np.sqrt(lam_c)))
        if not rows["crb"]:
            continue
        unit = (lambda v: float(np.degrees(v))) if axis < 3 else float
        out[f"{AXES[axis]}_{size:g}_within_{W}"] = {
            "placements": len(rows["crb"]),
            "crb_sigma_median": unit(np.median(rows["crb"])), "two_sample_sigma_median": unit(np.median(rows["two"])),
            "power_6dof": float(np.mean(rows["p6"])), "power_axes_1dof": float(np.mean(rows["pax"])),
            "power_oracle_1dof": float(np.mean(rows["por"])),
            "share_oracle_ge_95": float(np.mean(np.array(rows["por"]) >= 0.95)),
            "thresholds": {"6dof": float(h6), "axes_1dof": float(hax), "oracle_1dof": float(h1)}}
    return out


def site_geometry(cm, frames, T_world_cam: np.ndarray | None = None) -> dict:
    """What a site's traffic looks like from the camera (``cm``: a ``CameraMonitor``): matched
    pairs per frame, the matched boxes' depth along the view axis (median, 10-90 %), their spread
    off the axis (|x / z|, the lever a view-axis shift moves them by), camera height above the
    ground and pitch below the horizon (``T_world_cam``: the synthetic site's, z up, ground z=0;
    else from a plane fitted to the boxes' lowest corners in the LiDAR frame)."""
    from xcalib.calib.refine import match_frame

    pose = cm.pose0
    R, t = pose.R, pose.t
    npairs, depth, lever, bottoms, spread = [], [], [], [], []
    for f in frames:
        cf = cm._prepare(f)
        pairs, _, _ = match_frame(cf, cm.intr, R, t, gate_iou=0.2, gate_dist=0.5)
        npairs.append(len(pairs))
        if not len(pairs):
            continue
        c = np.asarray(cf.corners)[pairs[:, 1]]  # [m,S,3] LiDAR frame
        pc = c.mean(1) @ R.T + t
        depth.extend(pc[:, 2].tolist())
        lever.extend(np.abs(pc[:, 0] / pc[:, 2]).tolist())
        spread.append(float(np.ptp(pc[:, 2])) if len(pc) > 1 else 0.0)
        for box in c:
            bottoms.append(box[np.argmin(box[:, 2])])
    if T_world_cam is not None:
        height = float(T_world_cam[2, 3])
        axis = T_world_cam[:3, 2]
        pitch = float(np.degrees(np.arcsin(-axis[2])))
    else:  # ground plane z = a x + b y + c in the LiDAR frame from the boxes' lowest corners
        B = np.asarray(bottoms)
        A = np.column_stack([B[:, 0], B[:, 1], np.ones(len(B))])
        coef = np.linalg.lstsq(A, B[:, 2], rcond=None)[0]
        nrm = np.array([-coef[0], -coef[1], 1.0])
        nrm /= np.linalg.norm(nrm)
        C = -R.T @ t  # the camera centre in the LiDAR frame
        height = float(C @ nrm - coef[2] * nrm[2])
        axis = R.T @ np.array([0.0, 0.0, 1.0])
        pitch = float(np.degrees(np.arcsin(-axis @ nrm)))
    d = np.asarray(depth)
    return {"frames": len(frames), "pairs_per_frame": float(np.mean(npairs)),
            "depth_m_median": float(np.median(d)) if len(d) else None,
            "depth_m_p10_p90": [float(np.percentile(d, 10)), float(np.percentile(d, 90))] if len(d) else None,
            "depth_spread_per_frame_m_median": float(np.median(spread)) if spread else None,
            "off_axis_lever_median": float(np.median(lever)) if lever else None,
            "camera_height_m": height, "camera_pitch_down_deg": pitch}
