"""``Matcher``: a matching model with its config, crop settings and device.

``match(image, point_cloud, bboxes_2d, bboxes_3d)`` validates the inputs (protocol v1.0), crops
(``xcalib.data.crops.prepare_frame``, seeded so a call is deterministic), runs the model and
returns a :class:`xcalib.types.MatchResult` in the caller's numbering. ``embed`` / ``score``
expose the two model stages; ``prepare`` is the numpy-only part an ONNX Runtime path reuses.

A matcher may carry its site calibration (``set_calibration`` / ``calibration``; loaded from
``calibration.json`` beside site weights, written by ``save_pretrained``). ``match`` then fuses
the model's scores with the IoU of each 3D box projected through the calibration against each
2D box (``use_calibration="auto"``; see :mod:`xcalib.engine.fusion` for the formula).

A ``Matcher`` matches, embeds, scores, loads and saves. ``calibrate``, ``oneshot``, ``train``,
``build`` and ``from_onnx`` are thin delegations, kept for the reference package's API, to
:mod:`xcalib.calib.single` / :mod:`xcalib.calib.api`, :mod:`xcalib.oneshot.session`,
:func:`xcalib.engine.trainer.finetune`, :mod:`xcalib.deploy.build` and
:mod:`xcalib.deploy.ort_runtime` (imported lazily, so nothing below ``engine`` reaches up).
Other packages use its public interface only: ``validate_inputs``, ``warning_registry``,
``update_config``, ``crop_config``, ``similarity``, ``prepare``.
"""

from __future__ import annotations

import contextlib
import logging
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import torch

from ..data.crops import CropConfig, FrameInputs, prepare_frame
from ..protocol import WarningRegistry
from ..types import DatasetFrame, Frame, MatchResult, as_frame
from .host import (MATCH_FRAME_PARAMS, MATCH_POSITIONAL, MatchInputs, MatchOptions,  # noqa: F401 - torch-free,
                   assign, frame_match_args, match_request, run_match, validate_match_inputs)  # shared with ONNX Runtime
from ..options import document
from .domain import BOOTSTRAP_HINT
from .fusion import FUSION_WEIGHT, GEO_EPS
from ..errors import FormatError
from .checkpoint import (WeightsNotFoundError, find_site_weights, load_state_strict, probe_model, read_checkpoint,
                         read_config, save_weights, weights_in_dir, write_config)

__all__ = ["Matcher", "resolve_device", "assign", "without_shipped_weights_note"]

log = logging.getLogger("xcalib.matcher")
_SHIPPED_NOTE = "loading the shipped 'synthetic' weights"


class _NoShippedNote(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return _SHIPPED_NOTE not in str(record.msg)


@contextlib.contextmanager
def without_shipped_weights_note():
    """Within it, ``Matcher.from_pretrained`` does not warn that the shipped 'synthetic' weights do
    not know the user's site: for callers that know what they load (the demo on those weights' own
    synthetic site; ``xcalib bootstrap``, which starts from them to adapt them)."""
    quiet = _NoShippedNote()
    log.addFilter(quiet)
    try:
        yield
    finally:
        log.removeFilter(quiet)

CALIBRATION_FILE = "calibration.json"  # beside the weights (OneShotSession.save writes the same name)


def load_calibration_beside(weights_dir: Path):
    """The ``CalibrationResult`` in ``weights_dir/calibration.json``, or None when absent."""
    p = Path(weights_dir) / CALIBRATION_FILE
    if not p.is_file():
        return None
    from ..calib.result import CalibrationResult

    return CalibrationResult.load(p)


def _build_model(name: str, config: dict, weights_path, allow_random: bool):
    from ..models import create_model

    if weights_path is None and not allow_random:
        raise ValueError(f"Matcher({name!r}, ...): no weights_path given (argument or config['weights_path']); "
                         f"use Matcher.from_pretrained({name!r}, ...) for site or saved weights, or pass "
                         "allow_random=True for a randomly initialised model (testing only)")
    model = create_model(name, config or None)
    if weights_path is not None:
        load_state_strict(model, read_checkpoint(Path(weights_path))["state_dict"], str(weights_path))
    return model


def resolve_device(device: str | torch.device | None) -> torch.device:
    """None/"auto" -> cuda when available, else cpu."""
    if device is None or str(device) == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


class Matcher:
    """Model + config + device (+ optional site calibration). Build with :meth:`from_pretrained`
    or ``Matcher(model, config)``. ``fusion_weight`` / ``fusion_eps``: weight of the geometric
    score and its IoU clip when a calibration is set (:mod:`xcalib.engine.fusion`)."""

    def __init__(self, model_name: "str | torch.nn.Module", config: Mapping[str, Any] | None = None,
                 weights_path: str | Path | None = None, device: str | torch.device | None = None, *,
                 site: str | None = None, allow_random: bool = False):
        """The reference's constructor: ``Matcher(model_name, config, weights_path=None, device=None)``.

        ``model_name``: a registered name (unknown -> ``KeyError``) or an already built
        ``MatchingModel`` (used as is; ``weights_path`` then only records where its weights came
        from). With a name, the weights come from ``weights_path`` or ``config["weights_path"]``
        and are loaded strictly; none given -> ``ValueError`` unless ``allow_random=True``
        (testing). ``device``: argument, else ``config["device"]``, else "auto" (cuda when
        available)."""
        if isinstance(model_name, str):
            cfg = dict(config or {})
            weights_path = weights_path if weights_path is not None else cfg.pop("weights_path", None)
            device = device if device is not None else cfg.get("device")
            model = _build_model(model_name, cfg, weights_path, allow_random)
        else:
            model = model_name
        self.model = model
        self.model_name = model.model_name
        self.config = dict(model.config)
        self.device = resolve_device(device)
        self.model.to(self.device).eval()
        self.crop_config = CropConfig.from_config(self.config)
        self.weights_path = None if weights_path is None else Path(weights_path)
        self.site = site
        self.warning_registry = WarningRegistry()
        self._calibration = None
        self.fusion_weight = FUSION_WEIGHT
        self.fusion_eps = GEO_EPS

    @property
    def prepare_cfg(self) -> CropConfig:
        """The reference's name of :attr:`crop_config` (crop_size, point_cloud_size, bbox_expansion)."""
        return self.crop_config

    def update_config(self, **values: Any) -> None:
        """Set config keys of this matcher (written beside saved weights), e.g. a model's
        ``box_gain`` after adaptation; crop settings are re-read."""
        self.config.update(values)
        self.crop_config = CropConfig.from_config(self.config)

    # ------------------------------------------------------------------ calibration
    @property
    def calibration(self):
        """The site's ``CalibrationResult`` (``T_cam_lidar`` + intrinsics) or None."""
        return self._calibration

    def set_calibration(self, calibration) -> None:
        """Use ``calibration`` (a successful ``CalibrationResult`` with intrinsics) in ``match``;
        None removes it."""
        if calibration is not None:
            if not hasattr(calibration, "rotation") or not hasattr(calibration, "intrinsics"):
                raise TypeError(f"set_calibration: expected a CalibrationResult or None, got {type(calibration).__name__}")
            if not calibration.success:
                raise ValueError(f"set_calibration: the calibration failed ({calibration.message})")
            if calibration.intrinsics is None:
                raise ValueError("set_calibration: the calibration has no camera intrinsics (needed to project boxes)")
        self._calibration = calibration

    # ------------------------------------------------------------------ loading
    @classmethod
    def from_pretrained(cls, model: str, weights: str | Path | None = None,
                        config: str | Path | Mapping[str, Any] | None = None,
                        device: str | torch.device | None = None, *, site: str = "synthetic",
                        repo_id: str | None = None, revision: str | None = None,
                        token: str | None = None) -> "Matcher":
        """Load ``model`` with weights from the site folders (``weights=None``), a directory
        written by :meth:`save_pretrained`, or a weights file (the shipped ``synthetic`` site, also the
        default, loads with a warning naming ``xcalib bootstrap``). The config is ``config`` (YAML path
        or dict, merged onto the model defaults) or else the YAML beside the weights, else the
        one stored in the weights file. A checkpoint that does not fit is an error. Site folders
        and weights directories with a ``calibration.json`` give the matcher that calibration.
        ``repo_id`` / ``revision`` / ``token`` are accepted for API compatibility and rejected
        (xcalib never downloads weights)."""
        from ..models import create_model, default_config, merge_config
        from ..models.registry import model_class

        if repo_id is not None or revision is not None or token is not None:
            raise ValueError("Matcher.from_pretrained: xcalib never downloads weights (repo_id/revision/token "
                             f"given); expected weights=None (site folders, site={site!r}), a save_pretrained "
                             "directory or a weights file")

        model_class(model)  # unknown model -> UnknownModelError
        if weights is None and site == "synthetic":  # also the default: say what these weights are
            log.warning("Matcher.from_pretrained(%r): loading the shipped 'synthetic' weights (trained on one synthetic "
                        "site; they do not know yours: without a site calibration match() uses geometric consensus "
                        "when the intrinsics are known or their scores are out of domain). %s", model, BOOTSTRAP_HINT)
        if weights is None:
            path = find_site_weights(model, site)
        else:
            p = Path(weights)
            if p.is_dir():
                found = weights_in_dir(p, model)
                if found is None:
                    raise WeightsNotFoundError(f"no {model}.pt (or .pth) in weights directory {p}")
                path = found
            elif p.is_file():
                path = p
            else:
                raise WeightsNotFoundError(f"weights not found: {p}")
        payload = read_checkpoint(path)
        if payload.get("model_name", model) != model:
            raise ValueError(f"{path}: weights are for model {payload['model_name']!r}, not {model!r}")
        cfg_source = path
        if config is None:
            yaml_path = path.with_suffix(".yaml")
            cfg_source = yaml_path if yaml_path.is_file() else path
            cfg = read_config(yaml_path) if yaml_path.is_file() else payload.get("config") or default_config(model)
        elif isinstance(config, (str, Path)):
            cfg_source = Path(config)
            cfg = read_config(cfg_source)
        else:
            cfg = merge_config(default_config(model), config)
        if not isinstance(cfg, dict):
            raise FormatError(cfg_source, f"expected a config mapping, got {type(cfg).__name__}", "config")
        if cfg.get("model", model) != model:
            raise FormatError(cfg_source, f"config names model {cfg.get('model')!r}, but {model!r} was requested",
                              "model")
        probe_model(model, cfg, payload["state_dict"], cfg_source, path)  # meta device: nothing allocated
        net = create_model(model, cfg)
        load_state_strict(net, payload["state_dict"], str(path))
        try:
            out = cls(net, device=device, weights_path=path, site=site if weights is None else None)
        except (ValueError, TypeError, KeyError) as exc:  # crop / matching settings of the config
            raise FormatError(cfg_source, f"config settings are invalid ({type(exc).__name__}: {str(exc)[:200]})",
                              "config") from None
        if weights is None or Path(weights).is_dir():  # a site / saved folder: its calibration.json
            out.set_calibration(load_calibration_beside(path.parent))
        return out

    def save_pretrained(self, save_dir: str | Path, *, dtype: str = "float32", overwrite: bool = False,
                        extra_files: dict[str, bytes] | None = None, drop: tuple[str, ...] = ()) -> dict[str, Path]:
        """Write ``<dir>/<model>.pth`` (as the reference; directories load ``.pth`` or ``.pt``), its
        ``.sha256`` and ``<dir>/<model>.yaml`` (no device in either), and ``<dir>/calibration.json``
        when a calibration is set; an older ``<dir>/<model>.pt`` is removed (one set of weights
        per model in a folder). The files are written
        into a temporary folder and swapped in whole (other files of ``<dir>`` are kept), so a
        killed save leaves the old set or the new one. Existing weights of this model in ``<dir>``
        are replaced only with ``overwrite=True``. ``extra_files`` (file name -> bytes) are written
        in the same swap (a one-shot session's ``oneshot.json``); ``drop`` names files of the old
        folder the new set supersedes (not carried over)."""
        from ..io.files import atomic_dir, safe_name

        d = Path(save_dir)
        name = self.model_name
        old = weights_in_dir(d, name) if d.is_dir() else None
        if old is not None and not overwrite:
            raise FileExistsError(f"{old} already exists; pass overwrite=True to replace it")
        with atomic_dir(d, keep_existing=True, drop=[f"{name}.pt", *drop]) as tmp:
            for fname, data in (extra_files or {}).items():
                (tmp / safe_name(fname)).write_bytes(data)
            save_weights(self.model, tmp / f"{name}.pth", model_name=name, config=self.config, dtype=dtype)
            write_config(tmp / f"{name}.yaml", self.config)
            if self._calibration is not None:
                self._calibration.save(tmp / CALIBRATION_FILE)
        if (d / f"{name}.pt").is_file():  # an older save (.pt): the .pth and its sidecar replace it
            (d / f"{name}.pt").unlink()
        out = {"weights": d / f"{name}.pth", "config": d / f"{name}.yaml"}
        out.update({Path(f).stem: d / safe_name(f) for f in extra_files or {}})
        if self._calibration is not None:
            out["calibration"] = d / CALIBRATION_FILE
        return out

    # ------------------------------------------------------------------ stages
    def prepare(self, image, point_cloud, bboxes_2d, bboxes_3d, rng: np.random.Generator | None = None,
                **multi_camera) -> FrameInputs:
        """Numpy model inputs of one frame (crops, kept-index maps); deterministic by default."""
        return prepare_frame(image, point_cloud, bboxes_2d, bboxes_3d, self.crop_config, rng, **multi_camera)

    def batch(self, inputs: FrameInputs | list[FrameInputs]):
        from ..models.inputs import ModelBatch

        return ModelBatch.from_frames(inputs if isinstance(inputs, list) else [inputs], self.device)

    @torch.inference_mode()
    def embed(self, inputs: FrameInputs):
        """Stage 1: per-detection embeddings (``xcalib.models.Embeddings``) of one frame."""
        return self.model.embed(self.batch(inputs))

    @torch.inference_mode()
    def score(self, emb, inputs: FrameInputs) -> np.ndarray:
        """Stage 2: [N,M] similarity from embeddings."""
        return self.model.score(emb, self.batch(inputs)).float().cpu().numpy()

    @torch.inference_mode()
    def similarity(self, inputs: FrameInputs) -> np.ndarray:
        """[N,M] float32 similarity of prepared inputs (zeros-shaped when a side is empty)."""
        if inputs.empty:
            return np.zeros((inputs.num_2d, inputs.num_3d), dtype=np.float32)
        b = self.batch(inputs)
        return self.model.score(self.model.embed(b), b).float().cpu().numpy().astype(np.float32)

    # ------------------------------------------------------------------ matching
    def validate_inputs(self, image, point_cloud, bboxes_2d, bboxes_3d, mode: str = "warn") -> None:
        """Protocol v1.0 checks of one frame (``mode`` "off" | "warn" | "strict"): errors raise
        ``ProtocolError``; warnings are logged once per code by this matcher."""
        validate_match_inputs(image, point_cloud, bboxes_2d, bboxes_3d, mode,
                              bbox_expansion=self.crop_config.bbox_expansion, registry=self.warning_registry)

    @document(MatchOptions, positional=MATCH_POSITIONAL, extra=MATCH_FRAME_PARAMS)
    def match(self, image, point_cloud, bboxes_2d, bboxes_3d, *args: Any, options: MatchOptions | None = None,
              **overrides: Any) -> MatchResult:
        """Match one frame (the reference's positional order). ``latency_ms`` = crop + model (+
        projection and fusion) wall time (validation excluded), or the model's forward alone with
        ``return_latency=True``. ``use_calibration``: "auto" fuses the model's scores with the
        projection IoU through :attr:`calibration` when one is set (single-camera frames), True
        requires it, False gives the model's scores alone. ``box7`` [M,7]: optional yawed 3D boxes
        for the projection when ``bboxes_3d`` are axis-aligned [M,6]. ``geometry``: "auto" matches
        by geometric consensus (``MatchResult.source == "geometry"``) when the shipped off-site
        weights score the frame out of domain (:mod:`xcalib.engine.domain`), "on" always, "off"
        never; ``intrinsics`` (``CameraIntrinsics`` or 3x3 K) help it, else they are searched.
        ``match_threshold`` None: the site's threshold (chosen label-free by ``xcalib bootstrap``,
        saved in the model config as ``match_threshold``), else 0."""
        return run_match(self, *match_request((image, point_cloud, bboxes_2d, bboxes_3d), args, options, overrides),
                         score_range=getattr(self.model, "score_range", (-1.0, 1.0)),
                         fill_value=getattr(self.model, "fill_value", None))

    pair = match

    def match_frame(self, frame, **kw):
        """A :class:`xcalib.types.Frame` -> :meth:`match` (multi-camera frames crop each 2D box from
        its own camera's image) -> ``MatchResult``. Prepared inputs (``FrameInputs``, the
        reference's ``FrameData``) -> ``(scores [N,M] ndarray, forward ms)``, as the reference:
        no validation, no index mapping."""
        if isinstance(frame, FrameInputs):
            t0 = time.perf_counter()
            scores = self.similarity(frame)
            return scores, (time.perf_counter() - t0) * 1000.0
        args, kw = frame_match_args(as_frame(frame), kw)
        return self.match(*args, **kw)

    # ------------------------------------------------------------------ other tasks (thin delegations)
    def calibrate(self, *args, **kw):
        """The reference's one-frame form ``calibrate(image, point_cloud, bboxes_2d, bboxes_3d,
        intrinsics, *, match_threshold=0.5, ransac_reproj_px=8.0, validate="warn")``
        (:func:`xcalib.calib.single.calibrate_frame`), or ``calibrate(frames, intrinsics, **kw)``
        = :func:`xcalib.calib.api.calibrate` with this matcher's scores seeding the hypotheses."""
        if args and isinstance(args[0], np.ndarray) and args[0].ndim == 3:
            from ..calib.single import calibrate_frame, one_frame

            inputs, intrinsics, options = one_frame(*args, **kw)
            return calibrate_frame(self, inputs, intrinsics, **options)
        from ..calib import api

        if args and isinstance(args[0], (Frame, DatasetFrame)):
            args = ([args[0]], *args[1:])
        if args and isinstance(args[0], (list, tuple)):
            args = ([as_frame(f) for f in args[0]], *args[1:])
        return api.calibrate(*args, matcher=self, **kw)

    def oneshot(self, intrinsics, **options):
        """Label-free adaptation to a new site: ``xcalib.oneshot.OneShotSession(self, intrinsics,
        **options)`` (observe frames -> correspondence-free pose -> pseudo-labels -> adapt -> save)."""
        from ..oneshot.session import OneShotSession

        return OneShotSession(self, intrinsics, **options)

    def train(self, train_data, val_data, *, output_dir: str | Path = "runs/finetune", **kwargs) -> Path:
        """Fine-tune this matcher's model in place (:func:`xcalib.engine.trainer.finetune`; the
        best checkpoint by validation MRR is loaded back, strictly); returns the path of
        ``best.pth``. ``device`` defaults to the matcher's."""
        from .trainer import finetune

        best = finetune(self, train_data, val_data, output_dir=output_dir, **kwargs)
        self.weights_path = Path(best)
        return Path(best)

    # ------------------------------------------------------------------ deployment (xcalib.deploy)
    def build(self, target: str = "onnx", output_dir: str | Path | None = None, **kwargs):
        """Export for deployment: ``"onnx"`` graphs + manifest with a parity check, or ``"trt"``
        TensorRT engines via trtexec. See :func:`xcalib.deploy.build.build`."""
        from ..deploy.build import build

        return build(self, target, output_dir, **kwargs)

    @staticmethod
    def from_onnx(onnx_dir: str | Path, **kwargs):
        """Torch-free ONNX Runtime matcher (same ``match`` API) from a folder written by
        :meth:`build`. See :class:`xcalib.deploy.ort_runtime.OnnxMatcher`."""
        from ..deploy.ort_runtime import OnnxMatcher

        return OnnxMatcher(onnx_dir, **kwargs)

    def __repr__(self) -> str:
        cal = "" if self._calibration is None else ", calibrated=True"
        return (f"Matcher(model={self.model_name!r}, device={str(self.device)!r}, "
                f"weights={str(self.weights_path)!r}{cal})")
