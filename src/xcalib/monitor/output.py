"""What the monitor hands to operators: JSON lines, an HTML report with the change over time, and
an MCAP for Foxglove (``diagnostic_msgs/msg/DiagnosticArray`` on ``/diagnostics``, the estimated
LiDAR -> camera pose on ``/tf`` as ``foxglove.FrameTransforms``). Every file is written atomically.
"""

from __future__ import annotations

import html
import json
import os
import tempfile
from collections import deque
from pathlib import Path

import numpy as np

from ..geometry.rotations import matrix_to_quaternion
from ..geometry.transforms import invert_transform
from ..io.files import atomic_write
from ..viz.review import REVIEW_SCHEMAS
from .core import Monitor, MonitorStatus

__all__ = ["MonitorLog", "MonitorMcap", "write_monitor_html", "DIAGNOSTIC_SCHEMA", "LEVEL"]

#: diagnostic_msgs/DiagnosticStatus levels per state
LEVEL = {"ok": 0, "unknown": 1, "drift": 2}
_KV = {"type": "object", "properties": {"key": {"type": "string"}, "value": {"type": "string"}}}
DIAGNOSTIC_SCHEMA = {
    "title": "diagnostic_msgs/msg/DiagnosticArray", "type": "object",
    "properties": {
        "header": {"type": "object", "properties": {
            "stamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nanosec": {"type": "integer"}}},
            "frame_id": {"type": "string"}}},
        "status": {"type": "array", "items": {"type": "object", "properties": {
            "level": {"type": "integer"}, "name": {"type": "string"}, "message": {"type": "string"},
            "hardware_id": {"type": "string"}, "values": {"type": "array", "items": _KV}}}}},
}


class MonitorLog:
    """The decisions of a run, kept for the report (the last ``max_rows`` per camera: bounded memory)."""

    def __init__(self, max_rows: int = 50000):
        self.rows: dict[str, deque] = {}
        self.max_rows = max_rows

    def add(self, st: MonitorStatus) -> None:
        q = self.rows.setdefault(st.camera, deque(maxlen=self.max_rows))
        q.append((st.frame, st.time_s, st.state, np.r_[st.rotation_change_deg, st.translation_change_m],
                  np.r_[st.rotation_sigma_deg, st.translation_sigma_m]))


def _stamp(time_s: float) -> tuple[int, dict]:
    ns = int(round(max(time_s, 0.0) * 1e9)) + 1_000_000_000  # a relative clock, shifted off zero
    return ns, {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


class MonitorMcap:
    """Stream decisions into ``path`` (``with MonitorMcap(path, monitor) as m: m.add(status)``):
    ``/diagnostics`` one DiagnosticArray per decision (level 0 ok, 1 unknown, 2 drift; values: the
    change per axis, its sigma, the detectable change, the change frame), ``/tf`` the pose the
    monitor believes (``lidar_frame`` -> ``<camera>_optical_frame``) at each decision."""

    def __init__(self, path, monitor: Monitor, lidar_frame: str = "lidar"):
        self.path, self.monitor, self.lidar_frame = Path(path), monitor, lidar_frame
        self._tmp = None

    def __enter__(self) -> "MonitorMcap":
        from mcap.writer import Writer

        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, self._tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
        self._f = os.fdopen(fd, "wb")
        self.w = Writer(self._f)
        self.w.start(profile="", library="xcalib")
        s_diag = self.w.register_schema("diagnostic_msgs/msg/DiagnosticArray", "jsonschema",
                                        json.dumps(DIAGNOSTIC_SCHEMA).encode())
        s_tf = self.w.register_schema("foxglove.FrameTransforms", "jsonschema",
                                      json.dumps(REVIEW_SCHEMAS["foxglove.FrameTransforms"]).encode())
        self.c_diag = self.w.register_channel("/diagnostics", "json", s_diag)
        self.c_tf = self.w.register_channel("/tf", "json", s_tf)
        return self

    def add(self, st: MonitorStatus) -> None:
        ns, stamp = _stamp(st.time_s)
        vals = {"frame": st.frame, "state": st.state, "n_pairs": st.n_pairs,
                "change_frame": "" if st.change_frame is None else st.change_frame,
                "statistic": f"{st.statistic:.2f}", "threshold": f"{st.threshold:.2f}",
                "weak_axes": " ".join(st.weak_axes)}
        for name, arr, unit in (("rotation_change", st.rotation_change_deg, "deg"),
                                ("translation_change", st.translation_change_m, "m"),
                                ("rotation_sigma", st.rotation_sigma_deg, "deg"),
                                ("translation_sigma", st.translation_sigma_m, "m"),
                                ("detectable_rotation", st.detectable_rotation_deg, "deg"),
                                ("detectable_translation", st.detectable_translation_m, "m")):
            for ax, v in zip("xyz", np.asarray(arr, dtype=float)):
                vals[f"{name}_{ax}_{unit}"] = f"{v:.5g}"
        msg = {"header": {"stamp": stamp, "frame_id": ""},
               "status": [{"level": LEVEL[st.state], "name": f"xcalib monitor: {st.camera}", "message": st.message,
                           "hardware_id": st.camera, "values": [{"key": k, "value": str(v)} for k, v in vals.items()]}]}
        self.w.add_message(self.c_diag, ns, json.dumps(msg).encode(), ns)
        cm = self.monitor.cameras[st.camera]
        T = invert_transform(cm.estimated_pose().T)  # the camera's pose in the LiDAR frame
        q = matrix_to_quaternion(T[:3, :3])
        tf = {"transforms": [{"timestamp": {"sec": stamp["sec"], "nsec": stamp["nanosec"]},
                              "parent_frame_id": self.lidar_frame, "child_frame_id": f"{st.camera}_optical_frame",
                              "translation": {k: float(v) for k, v in zip("xyz", T[:3, 3])},
                              "rotation": {k: float(v) for k, v in zip("xyzw", q)}}]}
        self.w.add_message(self.c_tf, ns, json.dumps(tf).encode(), ns)

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.w.finish()
            self._f.close()
            if exc_type is None:
                os.chmod(self._tmp, 0o644)
                os.replace(self._tmp, self.path)
        finally:
            if os.path.exists(self._tmp):
                os.unlink(self._tmp)


_COLORS = ("#d62728", "#2ca02c", "#1f77b4")
_STATE_FILL = {"drift": "#f8d0d0", "unknown": "#e8e8e8"}


def _svg_panel(rows, k0: int, unit: str, scale: float, title: str, events) -> str:
    """One SVG line chart: axes x, y, z of rows' change (index k0..k0+2) with 2-sigma bands."""
    W, H, L, R, T, B = 900, 220, 60, 20, 24, 30
    t = np.array([r[1] for r in rows], dtype=float)
    y = np.array([r[3][k0:k0 + 3] for r in rows], dtype=float) * scale
    s = np.array([r[4][k0:k0 + 3] for r in rows], dtype=float) * scale
    fin = np.isfinite(y)
    lo = float(np.nanmin(np.where(fin, y - 2 * s, np.nan))) if fin.any() else -1.0
    hi = float(np.nanmax(np.where(fin, y + 2 * s, np.nan))) if fin.any() else 1.0
    lo, hi = (min(lo, 0.0), max(hi, 0.0)) if np.isfinite(lo) and np.isfinite(hi) else (-1.0, 1.0)
    if hi - lo < 1e-9:
        lo, hi = lo - 1, hi + 1
    t0, t1 = (float(t.min()), float(t.max())) if len(t) else (0.0, 1.0)
    t1 = t1 if t1 > t0 else t0 + 1

    def X(v):
        return L + (v - t0) / (t1 - t0) * (W - L - R)

    def Y(v):
        return T + (hi - v) / (hi - lo) * (H - T - B)

    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" style="background:#fff">',
           f'<text x="{L}" y="16" font-size="13">{html.escape(title)}</text>']
    for i, r in enumerate(rows):  # shade drift / unknown decisions
        if r[2] in _STATE_FILL:
            x0 = X(rows[i - 1][1]) if i else X(r[1]) - 1
            out.append(f'<rect x="{x0:.1f}" y="{T}" width="{max(X(r[1]) - x0, 1):.1f}" height="{H - T - B}" '
                       f'fill="{_STATE_FILL[r[2]]}"/>')
    out.append(f'<line x1="{L}" x2="{W - R}" y1="{Y(0):.1f}" y2="{Y(0):.1f}" stroke="#888" stroke-dasharray="3,3"/>')
    for ev in events:
        xe = X(ev.change_time_s)
        out.append(f'<line x1="{xe:.1f}" x2="{xe:.1f}" y1="{T}" y2="{H - B}" stroke="#000" stroke-width="1.5"/>'
                   f'<text x="{xe + 3:.1f}" y="{T + 12}" font-size="11">change (frame {ev.change_frame})</text>')
    for a in range(3):
        ok = fin[:, a]
        if not ok.any():
            continue
        pts = " ".join(f"{X(tt):.1f},{Y(v):.1f}" for tt, v in zip(t[ok], y[ok, a]))
        band = " ".join([f"{X(tt):.1f},{Y(v + 2 * e):.1f}" for tt, v, e in zip(t[ok], y[ok, a], s[ok, a])] +
                        [f"{X(tt):.1f},{Y(v - 2 * e):.1f}" for tt, v, e in
                         zip(t[ok][::-1], y[ok, a][::-1], s[ok, a][::-1])])
        out.append(f'<polygon points="{band}" fill="{_COLORS[a]}" fill-opacity="0.12" stroke="none"/>')
        out.append(f'<polyline points="{pts}" fill="none" stroke="{_COLORS[a]}" stroke-width="1.5"/>')
        out.append(f'<text x="{W - R - 60 + 20 * a}" y="16" font-size="12" fill="{_COLORS[a]}">{"xyz"[a]}</text>')
    for v in (lo, 0.0, hi):
        out.append(f'<text x="4" y="{Y(v) + 4:.1f}" font-size="11">{v:.3g} {unit}</text>')
    out.append(f'<text x="{L}" y="{H - 8}" font-size="11">{t0:.1f} s</text>'
               f'<text x="{W - R - 50}" y="{H - 8}" font-size="11">{t1:.1f} s</text></svg>')
    return "".join(out)


def write_monitor_html(path, monitor: Monitor, log: MonitorLog, *, title: str = "xcalib monitor") -> Path:
    """The report: the summary, and per camera the rotation (deg) and translation (cm) change
    relative to the calibration over time (window estimates, 2-sigma bands; drift shaded red,
    unknown grey; the change point marked)."""
    summ = monitor.summary()
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             "<style>body{font-family:sans-serif;margin:20px}td,th{padding:2px 8px;text-align:left}</style></head>"
             f"<body><h1>{html.escape(title)}</h1>",
             f"<p>State: <b>{summ['state']}</b> (exit code {summ['exit_code']}); {summ['frames']} frames; "
             f"false-alarm rate {summ['false_alarm_rate_per_frame']:g} per frame; chi-square threshold "
             f"{summ['threshold_chi2_6dof']:.1f} (6 dof).</p>"]
    for name, cs in summ["cameras"].items():
        cm = monitor.cameras[name]
        rows = list(log.rows.get(name, []))
        parts.append(f"<h2>{html.escape(name)}</h2><p>{html.escape(cs['message'])}</p>")
        dr, dt = cs.get("detectable_rotation_deg"), cs.get("detectable_translation_m")
        if dr is not None:
            parts.append("<p>Detectable change at the last decision (95 % power): rotation "
                         + ", ".join(f"{a} {v if v is None else round(v, 3)} deg" for a, v in zip("xyz", dr))
                         + "; translation "
                         + ", ".join(f"{a} {v if v is None else round(100 * v, 1)} cm" for a, v in zip("xyz", dt))
                         + "</p>")
        pw = cs.get("power")
        if pw is not None:
            parts.append(f"<p>Steps seen within {pw['within_frames']} frames of them ({100 * pw['power']:.0f} % power, "
                         f"median over {pw['decisions']} decisions): rotation "
                         + ", ".join(f"{a} {v if v is None else round(v, 3)} deg" for a, v in zip("xyz", pw["rotation_deg_median"]))
                         + "; translation "
                         + ", ".join(f"{a} {v if v is None else round(100 * v, 1)} cm"
                                     for a, v in zip("xyz", pw["translation_m_median"]))
                         + ". Not seen at the target size: "
                         + html.escape(", ".join(a for a, v in pw["seen_at_target"].items() if not v) or "none") + "</p>")
        parts.append("<table><tr><th>decisions</th>" + "".join(f"<td>{k}: {v}</td>" for k, v in
                                                               cs["decisions"].items()) + "</tr></table>")
        if rows:
            parts.append(_svg_panel(rows, 0, "deg", 1.0, "rotation change (deg, camera axes)", cm.events))
            parts.append("<br>" + _svg_panel(rows, 3, "cm", 100.0, "translation change (cm, camera axes)", cm.events))
        for ev in cm.events:
            parts.append(f"<pre>{html.escape(json.dumps(ev.to_dict(), indent=1))}</pre>")
    parts.append("</body></html>")
    return atomic_write(Path(path), ["".join(parts).encode()])
