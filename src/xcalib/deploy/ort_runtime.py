"""Torch-free ONNX Runtime matcher: the whole ``match`` flow with numpy + onnxruntime.

``OnnxMatcher(folder)`` reads a folder written by ``Matcher.build("onnx")`` (manifest + graphs),
checks the graph hashes, and offers the same ``match`` / ``match_frame`` / ``prepare`` /
``similarity`` API and :class:`xcalib.types.MatchResult` as :class:`xcalib.engine.matcher.Matcher`.
Steps: protocol validation, crops (:mod:`xcalib.data.crops`, seeded like the torch path), the
image / LiDAR embedding graphs, host-side scoring (cosine of L2-normalised embeddings; crlite's
per-row top-k + pair graph + sigmoid with -1 elsewhere; all-pairs graph + sigmoid), assignment.

With ``envelope=`` an :class:`~xcalib.deploy.chunking.Envelope` (or ``"protocol"``), every graph
call stays inside the engine envelope: larger frames are split into chunks along the graph's
batch axis and merged (a TensorRT runtime has to do the same). This module never imports torch.

A ``calibration.json`` in the folder (written by ``Matcher.build`` for a matcher with a site
calibration), or ``set_calibration``, makes ``match`` fuse the scores with the projection
geometry exactly as ``Matcher.match`` does (:mod:`xcalib.engine.fusion`, numpy only).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..data.crops import CropConfig, FrameInputs, prepare_frame
from ..engine.fusion import FUSION_WEIGHT, GEO_EPS
from ..engine.host import (MATCH_FRAME_PARAMS, MATCH_POSITIONAL, MatchOptions, frame_match_args,
                           match_request, run_match)
from ..options import document
from ..protocol import WarningRegistry
from ..types import Frame, MatchResult
from .chunking import PROTOCOL_ENVELOPE, Envelope, run_chunked
from .errors import EnvelopeError, OnnxFolderError
from .manifest import MANIFEST, Manifest, read_manifest
from .onnx_feeds import frame_feeds, pair_feeds

__all__ = ["OnnxMatcher", "OnnxModelInfo", "load_onnx", "resolve_folder", "l2_normalize"]

log = logging.getLogger("xcalib.deploy")


def l2_normalize(x: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Rows divided by max(L2 norm, eps) (as ``torch.nn.functional.normalize``)."""
    return x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), eps)


def resolve_folder(path: str | Path, model: str | None = None, site: str | None = None) -> Path:
    """``path`` itself when it holds a manifest, else its single ``<model>_<site>`` subfolder."""
    p = Path(path)
    if (p / MANIFEST).is_file() or not p.is_dir() or model is None:
        return p
    cands = sorted(p.glob(f"{model}_{site}" if site else f"{model}_*"))
    cands = [c for c in cands if (c / MANIFEST).is_file()]
    if len(cands) == 1:
        return cands[0]
    if not cands:
        raise OnnxFolderError(p, f"no manifest.json and no export folder for model {model!r}"
                                 f"{' site ' + repr(site) if site else ''} inside")
    raise OnnxFolderError(p, f"several export folders for model {model!r}: {[c.name for c in cands]}; pass site=")


@dataclass(frozen=True)
class OnnxModelInfo:
    """What ``Matcher.model`` offers to callers that only read it (no torch): name, family,
    ``fill_value`` of unscored pairs and the config."""

    model_name: str
    family: str
    fill_value: float | None
    config: dict


class OnnxMatcher:
    """ONNX Runtime matcher over an export folder. ``model`` / ``site``: expected values (a
    folder of another model or site is an error). ``providers``: onnxruntime execution
    providers (default CPU). ``threads``: intra-op threads (0 = onnxruntime default)."""

    def __init__(self, folder: str | Path, *, model: str | None = None, site: str | None = None,
                 providers: list[str] | None = None, envelope: Envelope | str | None = None,
                 threads: int = 0, verify_files: bool = True):
        import onnxruntime as ort

        self.folder = resolve_folder(folder, model, site)
        self.manifest: Manifest = read_manifest(self.folder, verify_files=verify_files)
        man, mpath = self.manifest, self.folder / MANIFEST
        if model is not None and man.model != model:
            raise OnnxFolderError(mpath, f"folder holds model {man.model!r}, but {model!r} was requested", "model")
        if site is not None and man.site != site:
            raise OnnxFolderError(mpath, f"folder holds weights of site {man.site!r}, but {site!r} was requested", "site")
        if isinstance(envelope, str):
            if envelope != "protocol":
                raise ValueError(f"envelope must be an Envelope, 'protocol' or None, got {envelope!r}")
            envelope = PROTOCOL_ENVELOPE
        self.envelope: Envelope | None = envelope
        self.model_name = man.model
        self.site = man.site
        self.config = dict(man.config)
        self.crop_config = CropConfig.from_config(self.config)
        self.family = man.family
        self.host: dict[str, Any] = dict(man.host)
        self.fill_value = self.host.get("fill_value")
        self.model = OnnxModelInfo(man.model, man.family, self.fill_value, dict(man.config))
        self.warning_registry = WarningRegistry()
        so = ort.SessionOptions()
        so.intra_op_num_threads = int(threads)
        so.inter_op_num_threads = 1
        self.providers = list(providers or ["CPUExecutionProvider"])
        self.sessions: dict[str, Any] = {}
        self.input_names: dict[str, list[str]] = {}
        self.output_names: dict[str, list[str]] = {}  # read once: a per-call get_outputs() costs
        for name, g in man.graphs.items():
            path = self.folder / g.file
            try:
                sess = ort.InferenceSession(str(path), so, providers=self.providers)
            except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own exception types
                raise OnnxFolderError(path, f"onnxruntime cannot load graph {name!r}: {exc}") from None
            have_in = [i.name for i in sess.get_inputs()]
            want_in = [t.name for t in g.inputs]
            if have_in != want_in:
                raise OnnxFolderError(path, f"graph inputs {have_in} differ from {want_in} in {MANIFEST}")
            self.sessions[name] = sess
            self.input_names[name] = have_in
            self.output_names[name] = [o.name for o in sess.get_outputs()]
        for need in ("image_embed", "lidar_embed") + (("pair_score",) if self.family != "cosine" else ()):
            if need not in self.sessions:
                raise OnnxFolderError(mpath, f"family {self.family!r} needs graph {need!r}; graphs: {sorted(self.sessions)}")
        self.device = f"onnxruntime:{self.sessions['image_embed'].get_providers()[0]}"
        self.score_range = (-1.0, 1.0) if self.family == "cosine" else (0.0, 1.0)
        self.fusion_weight, self.fusion_eps = FUSION_WEIGHT, GEO_EPS
        self._calibration = None
        if (self.folder / "calibration.json").is_file():
            from ..calib.result import CalibrationResult  # numpy only

            self.set_calibration(CalibrationResult.load(self.folder / "calibration.json"))

    @property
    def calibration(self):
        """The site's ``CalibrationResult`` or None (see ``Matcher.calibration``)."""
        return self._calibration

    def set_calibration(self, calibration) -> None:
        """As ``Matcher.set_calibration``: a successful ``CalibrationResult`` with intrinsics, or None."""
        if calibration is not None and (not calibration.success or calibration.intrinsics is None):
            raise ValueError("set_calibration: expected a successful CalibrationResult with intrinsics")
        self._calibration = calibration

    # ------------------------------------------------------------------ graphs
    def _max_rows(self, graph: str) -> int | None:
        if self.envelope is None:
            return None
        return self.envelope.profile(self.manifest.graphs[graph].role).max

    def run_graph(self, graph: str, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Run one graph (chunked along its batch axis inside the envelope, when set)."""
        sess = self.sessions[graph]
        names = self.input_names[graph]
        outs = self.output_names[graph]
        limit = self._max_rows(graph)

        def call(f: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
            n = len(next(iter(f.values())))
            if limit is not None and n > limit:  # a TensorRT engine would reject this call
                raise EnvelopeError(f"graph {graph!r}: {n} rows exceed the envelope maximum {limit}")
            return dict(zip(outs, sess.run(outs, f)))

        return run_chunked(call, {k: feeds[k] for k in names}, limit)

    def embed(self, inputs: FrameInputs) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """(image outputs {img_embed [N,E], ...}, LiDAR outputs {lid_embed [M,E], ...})."""
        img, lid = frame_feeds(inputs)
        if self.envelope is not None and self.host.get("joint_embedding"):
            for side, n, role in (("image", inputs.num_2d, "image"), ("LiDAR", inputs.num_3d, "lidar")):
                mx = self.envelope.profile(role).max
                if n > mx:
                    raise EnvelopeError(
                        f"{self.model_name} embeds a frame's detections jointly (graph over detections), so its "
                        f"{n} {side} detections cannot be split into chunks of the envelope maximum {mx}; "
                        "truncate the detections or run without an envelope")
        return self.run_graph("image_embed", img), self.run_graph("lidar_embed", lid)

    def similarity(self, inputs: FrameInputs) -> np.ndarray:
        """[N,M] float32 similarity of prepared inputs (same semantics as the torch model)."""
        N, M = inputs.num_2d, inputs.num_3d
        if inputs.empty:
            return np.zeros((N, M), dtype=np.float32)
        img, lid = self.embed(inputs)
        cos = (l2_normalize(img["img_embed"]) @ l2_normalize(lid["lid_embed"]).T).astype(np.float32)
        if self.family == "cosine":
            return cos
        if self.family == "hybrid":
            top_k = int(self.host.get("top_k") or 0)
            k = min(top_k, M) if top_k > 0 else M
            cols = np.argsort(-cos, axis=1, kind="stable")[:, :k]
            rows = np.repeat(np.arange(N), k)
            cols = cols.reshape(-1)
        else:
            rows, cols = np.repeat(np.arange(N), M), np.tile(np.arange(M), N)
        logit = self.run_graph("pair_score", pair_feeds(img, lid, rows, cols))["logit"].reshape(-1)
        prob = (1.0 / (1.0 + np.exp(-logit.astype(np.float64)))).astype(np.float32)
        fill = float(self.fill_value) if self.fill_value is not None else 0.0
        out = np.full((N, M), fill, dtype=np.float32)
        out[rows, cols] = prob
        return out

    # ------------------------------------------------------------------ matching (Matcher API)
    def prepare(self, image, point_cloud, bboxes_2d, bboxes_3d, rng: np.random.Generator | None = None,
                **multi_camera) -> FrameInputs:
        """Numpy model inputs of one frame (same crops as the torch ``Matcher.prepare``)."""
        return prepare_frame(image, point_cloud, bboxes_2d, bboxes_3d, self.crop_config, rng, **multi_camera)

    @document(MatchOptions, positional=MATCH_POSITIONAL, extra=MATCH_FRAME_PARAMS)
    def match(self, image, point_cloud, bboxes_2d, bboxes_3d, *args: Any, options: MatchOptions | None = None,
              **overrides: Any) -> MatchResult:
        """Match one frame (see ``Matcher.match``). ``latency_ms`` = crop + graphs + host scoring."""
        return run_match(self, *match_request((image, point_cloud, bboxes_2d, bboxes_3d), args, options, overrides),
                         score_range=self.score_range,
                         fill_value=self.fill_value)

    pair = match

    def match_frame(self, frame: Frame, **kw) -> MatchResult:
        """:meth:`match` on a :class:`xcalib.types.Frame` (multi-camera aware)."""
        args, kw = frame_match_args(frame, kw)
        return self.match(*args, **kw)

    def __repr__(self) -> str:
        return (f"OnnxMatcher(model={self.model_name!r}, site={self.site!r}, folder={str(self.folder)!r}, "
                f"providers={self.providers})")


def load_onnx(folder: str | Path, **kwargs) -> OnnxMatcher:
    """``OnnxMatcher(folder, **kwargs)``."""
    return OnnxMatcher(folder, **kwargs)
