"""2D object detection in camera images with an ONNX detector on the CPU (ONNX Runtime).

The package ships YOLOX-Nano (COCO, Apache-2.0, ``xcalib/weights/detectors/``); a user's own
detector of a common output layout is accepted too (:func:`load_detector`):

* ``yolox``: raw YOLOX head ``[1, N, 5 + C]`` (N = grid cells of strides 8/16/32; centre/size
  decoded here) or the same already decoded to input pixels; BGR 0-255 input, letterbox in the
  top-left corner padded with 114 (the official YOLOX demo);
* ``yolov5``: ``[1, N, 5 + C]`` (cx, cy, w, h in input pixels, objectness, class scores; N = 3
  anchors x grid cells); RGB 0-1 input, centred letterbox;
* ``yolov8``: ``[1, 4 + C, N]`` (cx, cy, w, h, class scores; no objectness); RGB 0-1, centred.

Scores are objectness x class probability (yolov8: the class score); class-agnostic NMS; boxes
in pixels of the original image, clipped to it. onnxruntime and onnx are the optional extra
``xcalib[onnx]``; a model is validated on load and a bad one raises
:class:`~xcalib.errors.FormatError` naming the file, the field and the problem.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Literal

import numpy as np

from ..errors import FormatError

__all__ = ["Detections2D", "Detector2D", "Detector2DConfig", "load_detector", "shipped_detector_path",
           "nms", "decode_yolox", "letterbox", "COCO_TRAFFIC", "SHIPPED_SHA256"]

Layout = Literal["auto", "yolox", "yolov5", "yolov8"]
COCO_TRAFFIC = ("person", "bicycle", "car", "motorcycle", "bus", "truck")
SHIPPED_SHA256 = "695e750a5d5754bb5a8d5325643b59282191a7e7a564e435a415fd3c578eab14"
MAX_MODEL_BYTES = 512 * 2**20  # a detector of this kind is a few MB to ~300 MB
_STRIDES = (8, 16, 32)


@dataclass(frozen=True)
class Detector2DConfig:
    """How the camera detector runs. ``input_long_side``: network input's long side in pixels
    (a multiple of 32; the short side follows the image's aspect) for models with a free input
    size; ``score_min`` / ``nms_iou``: kept score and NMS overlap; ``classes``: class names kept
    (empty: all); ``min_box_px``: smallest box side kept (pixels); ``threads``: ONNX Runtime
    intra-op threads."""

    input_long_side: int = 1280
    score_min: float = 0.3
    nms_iou: float = 0.45
    classes: tuple[str, ...] = COCO_TRAFFIC
    min_box_px: float = 8.0
    threads: int = 1
    layout: Layout = "auto"

    def __post_init__(self):
        if self.input_long_side < 64 or self.input_long_side % 32:
            raise ValueError(f"input_long_side must be a multiple of 32 >= 64, got {self.input_long_side}")
        if not 0 <= self.score_min < 1 or not 0 < self.nms_iou <= 1:
            raise ValueError(f"score_min in [0, 1) and nms_iou in (0, 1] wanted, got {self.score_min}, {self.nms_iou}")
        if self.layout not in ("auto", "yolox", "yolov5", "yolov8"):
            raise ValueError(f"layout must be auto, yolox, yolov5 or yolov8, got {self.layout!r}")


@dataclass(frozen=True)
class Detections2D:
    """One image's detections: ``boxes`` [K,4] float32 (x1, y1, x2, y2, pixels of the original
    image), ``scores`` [K] float32, ``class_ids`` [K] int64, ``class_names`` [K]."""

    boxes: np.ndarray
    scores: np.ndarray
    class_ids: np.ndarray
    class_names: tuple[str, ...] = field(default=())

    def __len__(self) -> int:
        return len(self.boxes)


def shipped_detector_path() -> Path:
    """The packaged YOLOX-Nano ONNX file."""
    return Path(str(resources.files("xcalib").joinpath("weights", "detectors", "yolox_nano.onnx")))


def _shipped_classes() -> tuple[str, ...]:
    p = resources.files("xcalib").joinpath("weights", "detectors", "coco_classes.txt")
    return tuple(s.strip() for s in p.read_text().splitlines() if s.strip())


def _ort():
    try:
        import onnx
        import onnxruntime as ort
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        raise ImportError("the camera detector needs ONNX Runtime: pip install 'xcalib[onnx]' "
                          f"(onnx and onnxruntime; missing: {exc.name})") from None
    return onnx, ort


# ----------------------------------------------------------------------------- pre/post-processing
def letterbox(image_rgb: np.ndarray, in_h: int, in_w: int, *, centred: bool) -> tuple[np.ndarray, float, float, float]:
    """Resize keeping the aspect into an ``in_h x in_w`` canvas padded with 114. Returns
    ``(canvas uint8 [in_h, in_w, 3], scale, pad_x, pad_y)``: input pixel = scale x image pixel + pad."""
    import cv2

    h, w = image_rgb.shape[:2]
    r = min(in_h / h, in_w / w)
    nh, nw = max(1, int(round(h * r))), max(1, int(round(w * r)))
    canvas = np.full((in_h, in_w, 3), 114, dtype=np.uint8)
    py, px = ((in_h - nh) // 2, (in_w - nw) // 2) if centred else (0, 0)
    canvas[py:py + nh, px:px + nw] = cv2.resize(image_rgb, (nw, nh), interpolation=cv2.INTER_LINEAR)
    return canvas, r, float(px), float(py)


def grid_cells(in_h: int, in_w: int) -> int:
    """Number of YOLOX head cells (strides 8, 16, 32) of an input size."""
    return sum((in_h // s) * (in_w // s) for s in _STRIDES)


def decode_yolox(raw: np.ndarray, in_h: int, in_w: int) -> np.ndarray:
    """Raw YOLOX head ``[N, 5 + C]`` (grid offsets, log sizes) -> centre/size in input pixels."""
    grids, strides = [], []
    for s in _STRIDES:
        hs, ws = in_h // s, in_w // s
        yv, xv = np.meshgrid(np.arange(hs), np.arange(ws), indexing="ij")
        grids.append(np.stack((xv, yv), -1).reshape(-1, 2))
        strides.append(np.full((hs * ws, 1), s))
    g, st = np.concatenate(grids), np.concatenate(strides)
    if len(g) != len(raw):
        raise ValueError(f"YOLOX head has {len(raw)} rows, {len(g)} expected for a {in_w}x{in_h} input")
    out = raw.astype(np.float64, copy=True)
    out[:, :2] = (out[:, :2] + g) * st
    out[:, 2:4] = np.exp(np.clip(out[:, 2:4], -20, 20)) * st
    return out


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """Greedy class-agnostic non-maximum suppression: indices kept, best first."""
    b = np.asarray(boxes, dtype=np.float64)
    order = np.argsort(-np.asarray(scores), kind="stable")
    area = np.clip(b[:, 2] - b[:, 0], 0, None) * np.clip(b[:, 3] - b[:, 1], 0, None)
    keep = []
    while order.size:
        i, rest = order[0], order[1:]
        keep.append(i)
        lt = np.maximum(b[i, :2], b[rest, :2])
        rb = np.minimum(b[i, 2:], b[rest, 2:])
        inter = np.prod(np.clip(rb - lt, 0, None), axis=1)
        order = rest[inter / (area[i] + area[rest] - inter + 1e-9) <= iou]
    return np.asarray(keep, dtype=np.int64)


def _cxcywh_to_xyxy(b: np.ndarray) -> np.ndarray:
    return np.column_stack([b[:, 0] - b[:, 2] / 2, b[:, 1] - b[:, 3] / 2, b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2])


# ----------------------------------------------------------------------------- the detector
class Detector2D:
    """An ONNX 2D detector run with ONNX Runtime on the CPU (see :func:`load_detector`)."""

    def __init__(self, session, path: Path, layout: str, classes: tuple[str, ...], fixed_hw, config: Detector2DConfig):
        self.session, self.path, self.layout, self.classes = session, path, layout, classes
        self.fixed_hw, self.config = fixed_hw, config
        self.input_name = session.get_inputs()[0].name
        keep = set(config.classes)
        self._keep_ids = None if not keep or not classes else np.array([c in keep for c in classes])
        if self._keep_ids is not None and not self._keep_ids.any():
            raise ValueError(f"none of the classes {sorted(keep)} is among the detector's: {', '.join(classes[:12])}...")

    def input_size(self, width: int, height: int) -> tuple[int, int]:
        """Network input (height, width) for an image: the model's fixed size, else the long side
        ``config.input_long_side`` and the short side from the aspect, both multiples of 32."""
        if self.fixed_hw is not None:
            return self.fixed_hw
        L = self.config.input_long_side
        s = L / max(width, height)
        short = max(32, int(np.ceil(min(width, height) * s / 32)) * 32)
        return (short, L) if width >= height else (L, short)

    def __call__(self, image_rgb: np.ndarray) -> Detections2D:
        """Detections of one RGB uint8 image ``[H, W, 3]``."""
        img = np.asarray(image_rgb)
        if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
            raise ValueError(f"image must be [H, W, 3] uint8 RGB, got {img.shape} {img.dtype}")
        H, W = img.shape[:2]
        in_h, in_w = self.input_size(W, H)
        yolox = self.layout in ("yolox", "yolox-decoded")
        canvas, r, px, py = letterbox(img[..., ::-1] if yolox else img, in_h, in_w, centred=not yolox)
        blob = canvas.transpose(2, 0, 1)[None].astype(np.float32)
        if not yolox:
            blob /= 255.0
        out = self.session.run(None, {self.input_name: np.ascontiguousarray(blob)})[0]
        return self._postprocess(np.asarray(out), in_h, in_w, (r, px, py), (W, H))

    def _postprocess(self, out: np.ndarray, in_h: int, in_w: int, affine, size) -> Detections2D:
        p = out.reshape(out.shape[-2], out.shape[-1]) if out.ndim == 3 else out
        if self.layout == "yolov8":
            p = p.T
            cls = p[:, 4:]
            obj = np.ones(len(p))
        else:
            if self.layout == "yolox":
                p = decode_yolox(p, in_h, in_w)
            obj, cls = p[:, 4], p[:, 5:]
        scores = obj[:, None] * cls
        if self._keep_ids is not None and len(self._keep_ids) == scores.shape[1]:
            scores = np.where(self._keep_ids[None], scores, 0.0)
        cid = scores.argmax(1)
        sc = scores[np.arange(len(cid)), cid]
        m = sc >= max(self.config.score_min, 1e-6)
        r, px, py = affine
        xyxy = (_cxcywh_to_xyxy(p[m, :4].astype(np.float64)) - [px, py, px, py]) / r
        W, H = size
        xyxy = np.clip(xyxy, 0, [W, H, W, H])
        sc, cid = sc[m], cid[m]
        ok = np.all(np.isfinite(xyxy), 1) & (np.minimum(xyxy[:, 2] - xyxy[:, 0], xyxy[:, 3] - xyxy[:, 1])
                                              >= self.config.min_box_px)
        xyxy, sc, cid = xyxy[ok], sc[ok], cid[ok]
        keep = nms(xyxy, sc, self.config.nms_iou)
        names = tuple(self.classes[c] if c < len(self.classes) else str(c) for c in cid[keep])
        return Detections2D(xyxy[keep].astype(np.float32), sc[keep].astype(np.float32), cid[keep].astype(np.int64),
                            names)


def _check_external_data(model, path: Path) -> None:
    """Every external-data location must be a plain relative name inside the model's folder."""
    folder = path.parent.resolve()
    for t in list(model.graph.initializer):
        for e in t.external_data:
            if e.key != "location":
                continue
            loc = Path(e.value)
            target = (folder / loc).resolve()
            if loc.is_absolute() or ".." in loc.parts or not target.is_relative_to(folder):
                raise FormatError(path, f"tensor {t.name!r} points to external data outside the model's folder "
                                        f"({e.value!r}); refused", "external_data")
            if not target.is_file():
                raise FormatError(path, f"tensor {t.name!r}: external data file {e.value!r} not found", "external_data")


def _dim(d) -> int | None:
    return int(d.dim_value) if d.HasField("dim_value") and d.dim_value > 0 else None


def _load_model(path: Path, onnx):
    if not path.is_file():
        raise FileNotFoundError(f"detector not found: {path}")
    if path.suffix.lower() != ".onnx":
        raise FormatError(path, f"expected an .onnx detector, got {path.suffix or 'no suffix'!r}")
    size = path.stat().st_size
    if size > MAX_MODEL_BYTES:
        raise FormatError(path, f"{size / 2**20:.0f} MB is larger than the {MAX_MODEL_BYTES // 2**20} MB allowed")
    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # noqa: BLE001 - protobuf raises several types on garbage
        raise FormatError(path, f"not a readable ONNX model ({type(exc).__name__}: {exc})") from None
    if not len(model.graph.input) or not len(model.graph.output):
        raise FormatError(path, "ONNX graph has no input or no output", "graph")
    _check_external_data(model, path)
    if any(e.key == "location" for t in model.graph.initializer for e in t.external_data):
        onnx.load_external_data_for_model(model, str(path.parent))
    return model


def _validate_io(model, path: Path):
    """(fixed input (h, w) or None, output dims) after checking the shapes a detector must have."""
    inits = {t.name for t in model.graph.initializer}
    inputs = [i for i in model.graph.input if i.name not in inits]
    if len(inputs) != 1:
        raise FormatError(path, f"a detector takes one image input, this model has {len(inputs)}: "
                                f"{[i.name for i in inputs]}", "graph.input")
    tt = inputs[0].type.tensor_type
    dims = [_dim(d) for d in tt.shape.dim]
    if len(dims) != 4 or dims[1] not in (3, None) or dims[0] not in (1, None):
        raise FormatError(path, f"input {inputs[0].name!r} must be [1, 3, H, W], got "
                                f"{[d if d is not None else '?' for d in dims]}", "graph.input")
    if tt.elem_type != 1:  # FLOAT
        raise FormatError(path, f"input {inputs[0].name!r} must be float32 (ONNX type 1), got type {tt.elem_type}",
                          "graph.input")
    odims = [_dim(d) for d in model.graph.output[0].type.tensor_type.shape.dim]
    if len(odims) not in (2, 3) or (len(odims) == 3 and odims[0] not in (1, None)):
        raise FormatError(path, f"output {model.graph.output[0].name!r} must be [1, N, 5+C] (YOLOX/YOLOv5) or "
                                f"[1, 4+C, N] (YOLOv8), got rank {len(odims)} {odims}", "graph.output")
    fixed = (dims[2], dims[3]) if dims[2] and dims[3] else None
    if fixed is not None and (fixed[0] < 32 or fixed[1] < 32 or fixed[0] > 4096 or fixed[1] > 4096):
        raise FormatError(path, f"input size {fixed[1]}x{fixed[0]} out of 32-4096", "graph.input")
    return fixed, odims


def _free_input(model):
    """The shipped YOLOX graph declares 416x416 but is fully convolutional: free H, W (and N)."""
    dims = model.graph.input[0].type.tensor_type.shape.dim
    dims[2].dim_param, dims[3].dim_param = "H", "W"
    model.graph.output[0].type.tensor_type.shape.dim[1].dim_param = "N"
    del model.graph.value_info[:]
    return model


def _infer_layout(out: np.ndarray, in_h: int, in_w: int, path: Path) -> str:
    """The output layout of a probe run on an ``in_h x in_w`` input."""
    if out.ndim == 3:
        out = out[0]
    if out.ndim != 2:
        raise FormatError(path, f"output must be [1, N, 5+C] or [1, 4+C, N], got {out.shape}", "graph.output")
    cells = grid_cells(in_h, in_w)
    a, b = out.shape
    if b >= 6 and a in (cells, 3 * cells) and a > b:
        if a == 3 * cells:
            return "yolov5"
        raw = float(np.nanmax(np.abs(out[:, 2:4]))) < 20.0  # log sizes (raw head) vs pixels (decoded)
        return "yolox" if raw else "yolox-decoded"
    if a >= 5 and b == cells and b > a:
        return "yolov8"
    raise FormatError(path, f"output {out.shape} of a {in_w}x{in_h} input matches no supported layout: YOLOX "
                            f"[{cells}, 5+C], YOLOv5 [{3 * cells}, 5+C], YOLOv8 [4+C, {cells}]", "graph.output")


def load_detector(path: str | Path | None = None, config: Detector2DConfig | None = None,
                  classes: tuple[str, ...] | None = None) -> Detector2D:
    """The shipped YOLOX-Nano (``path=None``) or a user's ONNX detector, validated and ready.

    ``classes``: class names in output order (default: COCO for 80 classes, else none: every
    class kept). Raises FormatError for a file that is not a usable detector, ImportError
    without ``xcalib[onnx]``."""
    config = config or Detector2DConfig()
    onnx, ort = _ort()
    shipped = path is None
    p = shipped_detector_path() if shipped else Path(path)
    if shipped and hashlib.sha256(p.read_bytes()).hexdigest() != SHIPPED_SHA256:
        raise FormatError(p, "the packaged detector's sha256 does not match; reinstall xcalib")
    model = _load_model(p, onnx)
    fixed, odims = _validate_io(model, p)
    if shipped:
        model, fixed = _free_input(model), None
    so = ort.SessionOptions()
    so.intra_op_num_threads = max(1, int(config.threads))
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    try:
        sess = ort.InferenceSession(model.SerializeToString(), so, providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001 - ORT raises its own exception types
        raise FormatError(p, f"ONNX Runtime cannot load the model ({type(exc).__name__}: {str(exc)[:300]})") from None
    in_h, in_w = fixed if fixed is not None else (320, 416)
    try:
        probe = sess.run(None, {sess.get_inputs()[0].name: np.zeros((1, 3, in_h, in_w), np.float32)})[0]
    except Exception as exc:  # noqa: BLE001
        raise FormatError(p, f"the model does not run on a [1, 3, {in_h}, {in_w}] input "
                             f"({type(exc).__name__}: {str(exc)[:300]})", "graph.input") from None
    probe = np.asarray(probe)
    layout = _infer_layout(probe, in_h, in_w, p)
    if config.layout != "auto" and config.layout != layout.split("-")[0]:
        raise FormatError(p, f"layout {config.layout!r} asked, but the output {probe.shape} is {layout}", "graph.output")
    n_cls = probe.shape[-2] - 4 if layout == "yolov8" else probe.shape[-1] - 5
    if classes is None:
        classes = _shipped_classes() if n_cls == 80 else ()
    elif len(classes) != n_cls:
        raise FormatError(p, f"{len(classes)} class names given, the model has {n_cls} classes", "classes")
    if not classes:
        config = dataclasses.replace(config, classes=())
    return Detector2D(sess, p, layout, tuple(classes), fixed, config)
