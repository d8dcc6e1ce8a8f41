"""One registry of calibration file formats: name -> writer + reader (+ content sniffing).

xcalib's own formats are :data:`FORMATS`, declared in the entry-point group ``xcalib.formats``
(:mod:`xcalib.plugins`) like any plugin's, so they are found the same way; a third-party package
adds one there with a :class:`CalibFormat` object::

    [project.entry-points."xcalib.formats"]
    kalibr_camchain = "my_pkg.camchain:FORMAT"   # CalibFormat(name, description, filename, write, read, sniff)

:func:`calib_formats` is every format, built-in and plugin; ``xcalib convert --to NAME`` writes
any of them and :func:`detect_format` asks each plugin's ``sniff(path) -> bool`` before the
generic guesses (any YAML is ROS, any text KITTI), so ``xcalib convert FILE`` and
``xcalib calibrate --prior FILE`` read a plugin's files too.

Every writer takes a :class:`~xcalib.calib.result.CalibrationResult` (``T_cam_lidar``: LiDAR ->
OpenCV camera) and returns the files it wrote; every reader returns a ``CalibrationResult`` with
the same direction, whatever the file's own convention (see each format module's docstring).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..calib.result import CalibrationResult
from ..errors import FormatError
from ..io.files import MAX_TEXT_BYTES, load_json, read_bytes
from ._checks import plausible_camera

__all__ = ["CalibFormat", "FORMATS", "calib_formats", "format_names", "export_calibration", "read_calibration",
           "detect_format", "default_filename"]


@dataclass(frozen=True)
class CalibFormat:
    """A calibration format: ``write(result, path) -> [paths]`` (None: read-only) and
    ``read(path, repair) -> CalibrationResult``; ``filename`` is the default output name;
    ``sniff(path) -> bool``: whether a file is of this format (detection on read; None: detected
    by :func:`detect_format`'s own rules, or only when named with ``--from``). ``models``: the camera
    models (``CameraModel.name``) whose intrinsics the written file can express; a result calibrated
    with another model is refused (:class:`~xcalib.formats.cameras.UnsupportedModelError`, nothing
    written) instead of written as a pinhole K of its fx, fy, cx, cy. None: any model (xcalib's own
    files), or a format without intrinsics (a pose only)."""

    name: str
    description: str
    filename: str
    write: Callable[..., list[Path]] | None
    read: Callable[..., CalibrationResult]
    sniff: Callable[[Path], bool] | None = None
    models: tuple[str, ...] | None = None


#: the camera models of a pinhole K with OpenCV radial-tangential distortion (or none)
PINHOLE_MODELS = ("pinhole", "pinhole_radtan")


# ----------------------------------------------------------------------------- adapters
def _w_kitti(res, path):
    from .kitti import KittiCalibration, write_kitti_calibration

    calib = KittiCalibration.from_calibration_result(res)
    if res.intrinsics.distortion is not None:
        import logging

        logging.getLogger("xcalib.formats").warning(
            "kitti calib files describe rectified images: the distortion %s is not written",
            res.intrinsics.distortion.tolist())
    return [write_kitti_calibration(calib, path)]


def _r_kitti(path, repair=False):
    from .kitti import load_kitti_calibration

    return load_kitti_calibration(path, repair=repair).to_calibration_result(2)


def _w_calib_json(res, path):
    from .calibanything import write_calib_json

    return [write_calib_json(res, path)]


def _r_calib_json(path, repair=False):
    from .calibanything import read_calib_json

    return read_calib_json(path, repair=repair)


def _w_lucid(res, path):
    from .calibanything import write_lucid_calib

    return [write_lucid_calib(res, path)]


def _r_lucid(path, repair=False):
    from .calibanything import read_lucid_calib

    return read_lucid_calib(path, repair=repair)


def _w_calib_txt(res, path):
    from .calibanything import write_calib_txt

    return [write_calib_txt(res, path)]


def _r_calib_txt(path, repair=False):
    from .calibanything import read_calib_txt

    return read_calib_txt(path, repair=repair)


def _w_opencalib(res, path):
    from .calibanything import write_opencalib

    p = Path(path)
    return [q for q in write_opencalib(res, p.parent if p.suffix and not p.is_dir() else p) if q is not None]


def _r_opencalib(path, repair=False):
    from .calibanything import read_opencalib

    p = Path(path)
    if p.is_dir():
        found = sorted(p.glob("*-extrinsic.json"))
        if not found:
            raise FormatError(p, "no *-extrinsic.json in the folder")
        p = found[0]
    return read_opencalib(p, repair=repair)


def _w_openlabel(res, path):
    from .openlabel import write_openlabel

    return [write_openlabel(res, path)]


def _r_openlabel(path, repair=False):
    from .openlabel import read_openlabel

    return read_openlabel(path, repair=repair)


def _w_ros(res, path):
    from .ros import write_ros

    return list(write_ros(res, path))


def _r_ros(path, repair=False):
    from .ros import read_ros

    return read_ros(path)


def _w_urdf(res, path):
    from .ros import write_urdf

    return [write_urdf(res, path)]


def _r_urdf(path, repair=False):
    from .ros import read_urdf

    return read_urdf(path)


def _w_tf_static(res, path):
    from .ros import write_tf_static

    return [write_tf_static(res, path)]


def _r_tf_static(path, repair=False):
    from .ros import read_tf_static

    return read_tf_static(path)


def _w_nuscenes(res, path):
    from .nuscenes import write_calibrated_sensor_json

    p = write_calibrated_sensor_json(res, path)
    return [p, p.parent / "sensor.json"]


def _r_nuscenes(path, repair=False):
    from .nuscenes import read_calibrated_sensor_json

    p = Path(path)
    return read_calibrated_sensor_json(p / "calibrated_sensor.json" if p.is_dir() else p)


def _w_json(res, path):
    return [res.save(Path(path).with_suffix(".json") if Path(path).suffix != ".json" else path)]


def _w_npz(res, path):
    return [res.save(Path(path).with_suffix(".npz") if Path(path).suffix != ".npz" else path)]


def _r_xcalib(path, repair=False):
    return CalibrationResult.load(path)


def _r_waymo(path, repair=False):
    from .waymo import read_waymo_tfrecord, waymo_calibration

    return waymo_calibration(read_waymo_tfrecord(path, max_frames=1)[0], "FRONT")


def _r_sustech(path, repair=False):
    from .sustech import read_sustech_calibration

    return read_sustech_calibration(path)


FORMATS: dict[str, CalibFormat] = {f.name: f for f in [
    CalibFormat("kitti", "KITTI calib txt (camera 2; a KITTI-born result keeps its P0-P3/R0_rect, else "
                         "P0-P3 = [K|0], R0_rect = I, Tr_velo_to_cam = T_cam_lidar)",
                "calib.txt", _w_kitti, _r_kitti, models=PINHOLE_MODELS),
    CalibFormat("calib_json", "CalibAnything v2 calib.json (T_lidar_to_cam, cam_K, cam_dist)", "calib.json",
                _w_calib_json, _r_calib_json, models=PINHOLE_MODELS),
    CalibFormat("lucid", "CalibAnything lucid_calib.json (camera pose in the LiDAR frame, roll/pitch/yaw deg)",
                "lucid_calib.json", _w_lucid, _r_lucid, models=PINHOLE_MODELS),
    CalibFormat("calib_txt", "CalibAnything v1 calib.txt (K:, D:, T: LiDAR->camera)", "calib_v1.txt",
                _w_calib_txt, _r_calib_txt, models=PINHOLE_MODELS),
    CalibFormat("opencalib", "OpenCalib <lidar>-to-<camera>-extrinsic.json + <camera>-intrinsic.json",
                "opencalib", _w_opencalib, _r_opencalib, models=PINHOLE_MODELS),
    CalibFormat("openlabel", "OpenLABEL coordinate_systems + streams (camera pose_wrt_parent = T_lidar_cam)",
                "openlabel.json", _w_openlabel, _r_openlabel, models=PINHOLE_MODELS),
    CalibFormat("ros", "ROS camera_info YAML + <stem>_tf.yaml static transform (lidar -> camera_optical pose)",
                "camera_info.yaml", _w_ros, _r_ros, models=PINHOLE_MODELS + ("kannala_brandt",)),
    CalibFormat("urdf", "URDF fixed joints: lidar -> <camera>_link (body) -> <camera>_optical_frame (no intrinsics)",
                "camera.urdf", _w_urdf, _r_urdf),
    CalibFormat("tf_static", "tf2_msgs/TFMessage YAML: lidar -> <camera>_optical_frame pose (no intrinsics)",
                "tf_static.yaml", _w_tf_static, _r_tf_static),
    CalibFormat("nuscenes", "nuScenes calibrated_sensor.json + sensor.json (sensor->ego, w,x,y,z)",
                "calibrated_sensor.json", _w_nuscenes, _r_nuscenes, models=PINHOLE_MODELS),
    CalibFormat("json", "xcalib CalibrationResult JSON", "calibration.json", _w_json, _r_xcalib),
    CalibFormat("npz", "xcalib CalibrationResult npz", "calibration.npz", _w_npz, _r_xcalib),
    CalibFormat("waymo", "Waymo segment .tfrecord (read only: FRONT camera, vehicle frame)", "", None, _r_waymo),
    CalibFormat("sustech", "SUSTechPOINTS calib/camera/<cam>.json (read only: extrinsic LiDAR -> camera, intrinsic K)",
                "", None, _r_sustech),
]}


#: One attribute per built-in format: the targets of xcalib's own ``xcalib.formats`` entry points
#: (``pyproject.toml``; :data:`xcalib.plugins.BUILTIN` when the package metadata is not installed).
KITTI = FORMATS["kitti"]
CALIB_JSON = FORMATS["calib_json"]
LUCID = FORMATS["lucid"]
CALIB_TXT = FORMATS["calib_txt"]
OPENCALIB = FORMATS["opencalib"]
OPENLABEL = FORMATS["openlabel"]
ROS = FORMATS["ros"]
URDF = FORMATS["urdf"]
TF_STATIC = FORMATS["tf_static"]
NUSCENES = FORMATS["nuscenes"]
JSON = FORMATS["json"]
NPZ = FORMATS["npz"]
WAYMO = FORMATS["waymo"]
SUSTECH = FORMATS["sustech"]

_PLUGINS: dict[str, CalibFormat] = {}  # loaded xcalib.formats entries (the registry's own bookkeeping)


def _registered_formats() -> dict[str, CalibFormat]:
    """The formats of the ``xcalib.formats`` entry points (by entry name), xcalib's own first: they
    are declared there too; one that fails to load or is no ``CalibFormat`` is reported
    (``xcalib.plugins.PluginWarning``) and left out."""
    import warnings

    from ..plugins import PluginWarning
    from ..plugins import entries as plugin_entries
    from ..plugins import load as load_plugin

    out = {}
    for entry in plugin_entries("xcalib.formats"):
        key = f"{entry.name}={entry.value}"
        if key not in _PLUGINS:
            obj = load_plugin(entry)
            if obj is None:
                continue
            if not isinstance(obj, CalibFormat):
                warnings.warn(f"xcalib plugin {entry.name!r} (xcalib.formats = {entry.value!r}, from {entry.dist}) is "
                              f"not a xcalib.formats.export.CalibFormat but {type(obj).__name__}", PluginWarning,
                              stacklevel=2)
                continue
            _PLUGINS[key] = obj
        out[entry.name] = _PLUGINS[key]
    return out


def calib_formats() -> dict[str, CalibFormat]:
    """Every calibration format by name, as the ``xcalib.formats`` entry points declare them:
    xcalib's own (:data:`FORMATS`), then the installed plugins'."""
    return _registered_formats()


def format_names(writable: bool = False) -> list[str]:
    return [n for n, f in calib_formats().items() if f.write is not None or not writable]


def default_filename(fmt: str) -> str:
    return _get(fmt).filename


def _get(fmt: str) -> CalibFormat:
    formats = calib_formats()
    if fmt not in formats:
        raise ValueError(f"unknown calibration format {fmt!r}; known: {', '.join(formats)}")
    return formats[fmt]


def export_calibration(result: CalibrationResult, fmt: str, path, *, overwrite: bool = True) -> list[Path]:
    """Write ``result`` in format ``fmt`` to ``path``; returns every file written.

    Every file of the format (ROS and nuScenes write two) is first written to a temporary folder
    beside the target, then moved into place; with ``overwrite=False`` an existing file among them
    is a FileExistsError and nothing is written."""
    import os
    import shutil
    import tempfile

    from ..io.files import tmp_prefix, check_overwrite, sweep_stale

    f = _get(fmt)
    if f.write is None:
        raise ValueError(f"format {fmt!r} is read-only; writable: {', '.join(format_names(True))}")
    if not result.success:
        raise ValueError(f"refusing to export a failed calibration ({result.message})")
    _check_model(result, f)
    path = Path(path)
    is_dir = fmt == "opencalib" and not path.suffix
    target = path if is_dir else path.parent
    target.mkdir(parents=True, exist_ok=True)
    sweep_stale(target, path.name)
    stage = Path(tempfile.mkdtemp(prefix=tmp_prefix(path.name), suffix=".tmp", dir=target))
    try:
        staged = [Path(p) for p in f.write(result, stage if is_dir else stage / path.name)]
        final = [target / p.relative_to(stage) for p in staged]
        for p in final:
            check_overwrite(p, overwrite)
        for s, p in zip(staged, final):
            os.replace(s, p)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return final


def _check_model(result: CalibrationResult, f: CalibFormat) -> None:
    """An UnsupportedModelError (nothing written) when ``f`` cannot express the result's camera model."""
    from .cameras import UnsupportedModelError

    intr = result.intrinsics
    name = None if intr is None else getattr(intr, "name", "pinhole_radtan")  # CameraIntrinsics: pinhole-radtan
    if f.models is None or name is None or name in f.models:
        return
    keep = [g.name for g in FORMATS.values() if g.write is not None and (g.models is None or name in g.models)]
    raise UnsupportedModelError(
        f"{f.name}: cannot express a {name} camera (its intrinsics are {' / '.join(f.models)}); nothing written "
        f"rather than a pinhole K of the lens's fx, fy, cx, cy. Formats that keep the {name} camera or hold "
        f"the pose alone: {', '.join(keep)}")


def detect_format(path) -> str:
    """Guess a calibration file's format from its name and content: xcalib's specific rules, then
    each plugin format's ``sniff``, then the generic guesses (a YAML is ROS, a text file KITTI)."""
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"calibration file not found: {p}")
    found = _detect_specific(p)
    if found is not None:
        return found
    for name, fmt in _registered_formats().items():  # xcalib's own have no sniff: their rules are above
        if fmt.sniff is not None and _sniffs(name, fmt, p):
            return name
    return _detect_generic(p)


def _sniffs(name: str, fmt: CalibFormat, p: Path) -> bool:
    """A plugin's ``sniff(p)``; one that raises is reported (PluginWarning) and taken as False."""
    import warnings

    from ..plugins import PluginWarning

    try:
        return bool(fmt.sniff(p))
    except Exception as exc:  # noqa: BLE001 - a broken plugin must not stop the detection of other formats
        warnings.warn(f"xcalib format plugin {name!r}: sniff({p}) failed: {type(exc).__name__}: {exc}", PluginWarning,
                      stacklevel=3)
        return False


def _detect_specific(p: Path) -> str | None:
    """The built-in formats a file's name or content identifies; None where only a generic guess is left."""
    if p.is_dir():
        if (p / "calibrated_sensor.json").is_file():
            return "nuscenes"
        if any(p.glob("*-extrinsic.json")):
            return "opencalib"
        return None
    name = p.name.lower()
    if name.endswith(".npz"):
        return "npz"
    if name.endswith((".urdf", ".xacro")) or (name.endswith(".xml") and "<robot" in p.read_text(errors="replace")):
        return "urdf"
    if name.endswith((".yaml", ".yml")):
        head = p.read_text(errors="replace")
        return "tf_static" if any(line.startswith("transforms:") for line in head.splitlines()) else None
    if ".tfrecord" in name:
        return "waymo"
    if name.endswith(".pkl"):
        return "kitti"
    if name.endswith(".json"):
        d = load_json(p, what="calibration file")
        if isinstance(d, list):
            return "nuscenes"
        if isinstance(d, dict):
            if d.get("format") == "xcalib-calibration-v1":
                return "json"
            if "openlabel" in d:
                return "openlabel"
            if "intrinsic_params" in d or "extrinsic_params" in d:
                return "lucid"
            if "cam_K" in d or "T_lidar_to_cam" in d:
                return "calib_json"
            if len(d) == 1 and str(next(iter(d))).endswith("-extrinsic"):
                return "opencalib"
            if "extrinsic" in d and "intrinsic" in d:
                return "sustech"
        return None
    text = read_bytes(p, max_bytes=MAX_TEXT_BYTES, what="calibration file").decode("utf-8", errors="replace")
    keys = {line.split(":", 1)[0].strip() for line in text.splitlines() if ":" in line}
    if {"K", "T"} <= keys:
        return "calib_txt"
    return None


def _detect_generic(p: Path) -> str:
    """The guess for a file no specific rule nor plugin claimed (or the FormatError naming it)."""
    if p.is_dir():
        raise FormatError(p, "folder is neither a nuScenes table folder nor an OpenCalib folder")
    name = p.name.lower()
    if name.endswith((".yaml", ".yml")):
        return "ros"
    if name.endswith(".json"):
        raise FormatError(p, "unrecognised calibration JSON (expected xcalib, lucid_calib, calib.json, "
                             "OpenLABEL, OpenCalib, calibrated_sensor or SUSTechPOINTS)")
    return "kitti"


def read_calibration(path, fmt: str | None = None, *, repair: bool = False) -> CalibrationResult:
    """Read any supported calibration file (format detected when ``fmt`` is None)."""
    from ..calib.result import validate_loaded

    fmt = fmt or detect_format(path)
    reader = _get(fmt).read
    try:
        result = reader(path, repair=repair)
    except FormatError as exc:
        if exc.path is None:  # a helper that did not know the file
            raise FormatError(path, exc.problem, exc.field) from None
        raise
    except (ValueError, TypeError, OverflowError, RecursionError, IndexError, AttributeError) as exc:
        raise FormatError(path, f"not a readable {fmt} calibration ({type(exc).__name__}: {str(exc)[:200]})") from None
    validate_loaded(result, path)
    plausible_camera(result.intrinsics, path)  # a camera's numbers, not corrupt ones
    return result


