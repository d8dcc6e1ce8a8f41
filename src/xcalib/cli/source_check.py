"""``xcalib validate SOURCE``: read every frame of a frame source and say what a calibration will
see (frames, 2D / 3D boxes, points, intrinsics, recorded poses, labels, times) and what is missing.

A check of the input only: nothing is matched or calibrated. Unreadable frames are listed with the
reader's error (the file and field it names); the report is JSON-able (``--json`` / ``--output``).

Images: a frame folder's and an HDF5 cache's PNG / JPEG images are not decoded, their sizes are read
from their headers, except in a sample of :data:`DECODED_SAMPLE` frames spread over the checked ones
(first, middle, last), which are decoded whole; ``decode=True`` (``--decode``) decodes every image.
Other sources' readers decode every image they read.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import FormatError

REPORT_SCHEMA = "xcalib.source_check/1"
MAX_ERRORS = 20  # unreadable frames listed one by one; the rest counted
DECODED_SAMPLE = 3  # frames whose images are decoded whole when the others' sizes come from headers
#: the sources whose readers can give an image's size without decoding it, and the option that does
_HEADER_ONLY = {"frame-folder": {"decode_images": False}, "hdf5-cache": {"decode_images": False}}


def _spread(values: list[int]) -> dict:
    a = np.asarray(values, dtype=np.int64)
    if a.size == 0:
        return {"min": 0, "median": 0, "max": 0, "frames_without": 0}
    return {"min": int(a.min()), "median": float(np.median(a)), "max": int(a.max()),
            "frames_without": int((a == 0).sum())}


def _sample(n: int) -> set[int]:
    """Up to ``DECODED_SAMPLE`` frame indices spread over ``range(n)`` (first, middle, last)."""
    if n <= DECODED_SAMPLE:
        return set(range(n))
    return {round(k * (n - 1) / (DECODED_SAMPLE - 1)) for k in range(DECODED_SAMPLE)}


def check_source(source: Path, *, camera: str | None = None, limit: int | None = None, decode: bool = False) -> dict:
    """The check's report of ``source`` (its first ``limit`` frames); the source's own open errors
    (not a frame source, several cameras without ``camera``) propagate. ``decode``: decode every
    image (else see the module docstring)."""
    from ..io.sources import find_source, image_size_of, open_source

    kind = find_source(source).name
    sensors_only = False
    try:
        seq = open_source(source, camera=camera)
    except FormatError as exc:  # a bag of sensors only (bag write --no-detections): checked as such
        if kind != "bag" or exc.field not in ("--detections-2d", "--detections-3d"):
            raise
        seq, sensors_only = open_source(source, camera=camera, detections=False), True
    n = len(seq) if limit is None else max(0, min(int(limit), len(seq)))
    fast = seq if decode or kind not in _HEADER_ONLY else open_source(source, camera=camera, **_HEADER_ONLY[kind])
    whole = set(range(n)) if fast is seq else _sample(n)
    sizes: dict[str, int] = {}
    counts: dict[str, list[int]] = {"boxes_2d": [], "boxes_3d": [], "points": []}
    has = {"intrinsics": 0, "recorded_pose": 0, "labels": 0, "times": 0, "image": 0}
    cams: dict[str, int] = {}
    errors: list[str] = []
    n_bad = 0
    intr = None
    for i in range(n):
        try:
            f = (seq if i in whole else fast)[i]
        except (FormatError, OSError, ValueError) as exc:  # the reader's own error, naming file and field
            n_bad += 1
            if len(errors) < MAX_ERRORS:
                errors.append(f"frame {i}: {exc}")
            continue
        counts["boxes_2d"].append(len(f.bboxes_2d))
        counts["boxes_3d"].append(len(f.bboxes_3d))
        counts["points"].append(len(f.point_cloud))
        has["intrinsics"] += f.intrinsics is not None
        has["recorded_pose"] += f.extrinsics is not None
        has["labels"] += f.match_matrix is not None
        has["times"] += f.lidar_time_s is not None and f.camera_time_s is not None
        size = image_size_of(f)
        has["image"] += size is not None
        if size is not None:
            sizes[f"{size[0]}x{size[1]}"] = sizes.get(f"{size[0]}x{size[1]}", 0) + 1
        cams[f.camera_name or "camera"] = cams.get(f.camera_name or "camera", 0) + 1
        if intr is None and f.intrinsics is not None:
            intr = f.intrinsics
    read = n - n_bad
    report = {"_schema": REPORT_SCHEMA, "source": str(source), "kind": kind, "frames": len(seq), "checked": n,
              "read": read, "unreadable": n_bad, "errors": errors, "cameras": cams,
              "images_decoded": len(whole), "image_sizes": sizes, "sensors_only": sensors_only,
              **{k: _spread(v) for k, v in counts.items()}, "with": has,
              "intrinsics": None if intr is None else {"fx": float(intr.fx), "fy": float(intr.fy),
                                                       "cx": float(intr.cx), "cy": float(intr.cy),
                                                       "width": intr.width, "height": intr.height}}
    report["missing"] = _missing(report)
    report["readable"] = read > 0 and n_bad == 0
    return report


def _missing(r: dict) -> list[str]:
    """What a calibration of these frames lacks, each with what to do."""
    read = r["read"]
    out = ["the bag has no detection topics (checked as a sensors-only recording)"] if r.get("sensors_only") else []
    if read == 0:
        if r["checked"]:
            return ["no frame could be read"]
        return ["no frame checked (--limit-frames 0)" if r["frames"] else "the source holds no frames"]
    if r["boxes_2d"]["frames_without"] == read:
        out.append("no 2D boxes in any frame: calibrate --detect (or xcalib detect SOURCE --out FILE.mcap) "
                   "detects them")
    if r["boxes_3d"]["frames_without"] == read:
        out.append("no 3D boxes in any frame: calibrate --detect (or xcalib detect) makes label-free LiDAR boxes")
    if r["points"]["frames_without"]:
        out.append(f"{r['points']['frames_without']} frame(s) without LiDAR points")
    if r["with"]["intrinsics"] < read:
        out.append(f"camera intrinsics missing in {read - r['with']['intrinsics']} of {read} frame(s): pass "
                   "calibrate --intrinsics FILE")
    return out


def print_check(r: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    con = Console()
    cams = ", ".join(f"{c} ({k})" for c, k in r["cameras"].items()) or "-"
    con.print(f"{r['source']} ({r['kind']}): {r['frames']} frame(s); checked {r['checked']}, read {r['read']}, "
              f"unreadable {r['unreadable']}; camera(s): {cams}")
    t = Table(title="per frame")
    for col in ("", "min", "median", "max", "frames without"):
        t.add_column(col, justify="right")
    for k, label in (("boxes_2d", "2D boxes"), ("boxes_3d", "3D boxes"), ("points", "LiDAR points")):
        s = r[k]
        t.add_row(label, str(s["min"]), f"{s['median']:g}", str(s["max"]), str(s["frames_without"]))
    con.print(t)
    w, read = r["with"], r["read"]
    intr = r["intrinsics"]
    size = f", {intr['width']}x{intr['height']}" if intr and intr["width"] else ""
    con.print(f"intrinsics: {w['intrinsics']} of {read}" + (f" (fx {intr['fx']:g}, fy {intr['fy']:g}{size})"
                                                             if intr else "")
              + f"; recorded pose: {w['recorded_pose']}; labels (match matrix): {w['labels']}; "
              f"LiDAR and camera times: {w['times']}; images: {w['image']}", highlight=False)
    if r["image_sizes"]:
        decoded = ("every image decoded" if r["images_decoded"] >= r["checked"] else
                   f"{r['images_decoded']} decoded, the others' sizes from their headers (--decode: decode all)")
        con.print("image sizes: " + ", ".join(f"{s} ({k})" for s, k in r["image_sizes"].items()) + f"; {decoded}",
                  highlight=False)
    for e in r["errors"]:
        con.print(f"[red]unreadable[/red] {e}", highlight=False, markup=True)
    if r["unreadable"] > len(r["errors"]):
        con.print(f"... and {r['unreadable'] - len(r['errors'])} more unreadable frame(s)")
    for m in r["missing"]:
        con.print(f"missing: {m}", highlight=False)
    if r["readable"] and not r["missing"]:
        con.print(f"Next: xcalib calibrate {r['source']}", highlight=False)
    con.print("(xcalib validate --hdf5 CACHE evaluates matchers on a labelled HDF5 cache)", highlight=False)
