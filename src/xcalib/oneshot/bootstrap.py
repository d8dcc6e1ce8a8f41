"""``bootstrap``: a recording of a new site -> site weights, with no matcher to start with.

1. calibrate the rig from the detections alone (correspondence-free bring-up over the frames);
2. pseudo-label every frame by projecting its 3D boxes through that pose;
3. train a matcher on the pseudo-labels: from the weights of ``init`` (a site or a weights
   file; "auto" = the packaged ``synthetic`` site when present) with the heads mode, or from
   random weights with the full mode ("scratch");
4. choose the site's match threshold from the pseudo-labels (``oneshot.threshold``; saved in the
   model config, used by ``match`` when no ``match_threshold`` is given); decide the site's default
   matching path (``oneshot.site_default``: geometry unless the adapted model alone reproduces the
   pose-only matches on the held-out frames; saved in the model config as ``site_default``);
   check the held-out Top-1 (``oneshot.heldout``: a quarter of the frames, at least 4, held out of
   training; reported only when it agrees with the matches of a pose calibrated without them);
5. install the weights (and ``calibration.json``) where ``Matcher.from_pretrained(model, site=SITE)``
   finds them (``$XCALIB_HOME/sites/<site>/``), unless ``install=False``; the reloaded matcher
   carries that calibration and fuses it into ``match``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from ..calib.config import CalibConfig
from ..calib.result import CalibrationResult
from ..io.files import claim_output
from .heldout import HELDOUT_SHARE, MIN_HELDOUT_FRAMES, HeldoutCheck, check_heldout
from .site_default import SiteDefault, choose_site_default
from .threshold import ThresholdChoice, choose_threshold
from ..types import Frame
from .adapt import AdaptOptions, AdaptReport
from ..options import Options, document, resolve

__all__ = ["BootstrapResult", "BootstrapOptions", "bootstrap", "starting_matcher"]

THRESHOLD_FRAMES = 32  # frames kept to choose the site's match threshold (label-free, ``oneshot.threshold``)

log = logging.getLogger("xcalib.oneshot")


@dataclass
class BootstrapResult:
    """Outcome of :func:`bootstrap`: where the weights went, the pose, the training report, and
    the trained ``matcher`` (carrying the pose: its ``match`` fuses model and projection)."""

    site: str
    model: str
    init: str
    n_frames: int
    calibration: CalibrationResult
    adapt: AdaptReport
    paths: dict[str, Path] = field(default_factory=dict)
    elapsed_s: float = 0.0
    matcher: object = None
    threshold: ThresholdChoice | None = None
    site_default: SiteDefault | None = None
    heldout: HeldoutCheck | None = None

    def summary(self) -> dict:
        c = self.calibration
        return {"site": self.site, "model": self.model, "init": self.init, "frames": self.n_frames,
                "calibrated": bool(c.success), "calibration_pairs": c.n_pairs,
                "calibration_iou_median": c.iou_median, "calibration_residual_px_median": c.residual_px_median,
                "T_cam_lidar": c.extrinsics.tolist() if c.success else None, "adapt": {k: v for k, v in self.adapt.to_dict().items()
                                                                if k != "losses"},
                "paths": {k: str(v) for k, v in self.paths.items()}, "elapsed_s": self.elapsed_s,
                "match_threshold": None if self.threshold is None else dataclasses.asdict(self.threshold),
                "site_default": None if self.site_default is None else dataclasses.asdict(self.site_default),
                "heldout": None if self.heldout is None else {**dataclasses.asdict(self.heldout),
                                                               "reported_top1": self.heldout.reported_top1}}


def starting_matcher(model: str, init: str = "auto", *, device: str | None = "cpu", seed: int = 0):
    """(Matcher, description, adapt mode) to start from: site weights, a weights path, or random."""
    import torch

    from ..engine.checkpoint import WeightsNotFoundError
    from ..engine.matcher import Matcher, without_shipped_weights_note
    from ..models import create_model

    if init in ("auto", "synthetic"):
        try:
            with without_shipped_weights_note():  # (it would advise running bootstrap, which this is)
                return Matcher.from_pretrained(model, site="synthetic", device=device), "site:synthetic", "heads"
        except WeightsNotFoundError:
            if init == "synthetic":
                raise
            log.info("bootstrap: no %s weights for site 'synthetic'; training from scratch", model)
            init = "scratch"
    if init == "scratch":
        torch.manual_seed(seed)
        return Matcher(create_model(model), device=device), "scratch", "full"
    p = Path(init)
    if p.exists():
        return Matcher.from_pretrained(model, weights=p, device=device), f"weights:{p}", "heads"
    return Matcher.from_pretrained(model, site=init, device=device), f"site:{init}", "heads"


@dataclass(frozen=True)
class BootstrapOptions(Options):
    """The settings of :func:`bootstrap` (the defaults in one place): model (registered name),
    init ("auto" | "scratch" | a site; see :func:`starting_matcher`), steps (adaptation steps), mode
    (None: the starting point's), lr, holdout (share of frames held out), install (into the user
    site folder), out_dir (also, or with ``install=False`` only, save there), device, seed,
    calib_config, on_frame (``(n, ObserveReport)`` callback), on_step (``(step, total, loss)``)."""

    model: str = "fastmatch"
    init: str | Path = "auto"
    steps: int = 600
    mode: str | None = None
    lr: float = AdaptOptions.lr
    holdout: float = HELDOUT_SHARE
    install: bool = True
    out_dir: str | Path | None = None
    device: Any = "cpu"  # str or torch.device; None: the default
    seed: int = 0
    calib_config: CalibConfig | None = None
    on_frame: Callable[[int, object], None] | None = None
    on_step: Callable[[int, int, float], None] | None = None


@document(BootstrapOptions)
def bootstrap(frames: Iterable[Frame], intrinsics, site: str, *, options: BootstrapOptions | None = None,
              **overrides: Any) -> BootstrapResult:
    """Site weights from unlabelled frames (see the module docstring).

    Settings: a :class:`BootstrapOptions` (``options=``) and/or its fields as keyword arguments
    (model, init, steps, mode, lr, holdout, install, out_dir, device, seed, calib_config, on_frame,
    on_step). Raises ``OneShotError`` when the frames do not determine a pose (nothing is written
    then). ``out_dir``: also (or, with ``install=False``, only) save there.
    """
    o = resolve(BootstrapOptions, options, overrides, where="bootstrap")
    model, init, steps, mode, lr, holdout, install = o.model, o.init, o.steps, o.mode, o.lr, o.holdout, o.install
    out_dir, device, seed, calib_config, on_frame, on_step = o.out_dir, o.device, o.seed, o.calib_config, \
        o.on_frame, o.on_step
    from ..engine.checkpoint import site_dirs
    from .session import OneShotError, OneShotSession

    with contextlib.ExitStack() as claims:  # outputs claimed before any work: a second run is refused at once
        if install:
            if not site or any(c in site for c in "/\\") or site in (".", ".."):
                raise ValueError(f"site: expected a plain folder name, got {site!r}")
            claims.enter_context(claim_output(site_dirs(site)[0], f"site {site!r}"))
        if out_dir is not None:
            claims.enter_context(claim_output(out_dir, "output folder"))
        t0 = time.perf_counter()
        matcher, init_desc, default_mode = starting_matcher(model, init, device=device, seed=seed)
        session = OneShotSession(matcher, intrinsics, mode=mode or default_mode, seed=seed, calib_config=calib_config)
        n, kept = 0, []
        for n, frame in enumerate(frames, start=1):
            rep = session.observe_frame(frame, validate="off")
            if len(kept) < THRESHOLD_FRAMES:
                kept.append(frame)
            if on_frame is not None:
                on_frame(n, rep)
        if n == 0:
            raise OneShotError("bootstrap: no frames in the recording")
        last = session.calibrate()  # a last attempt on the whole recording (the gate keeps the better pose)
        if not session.is_calibrated:
            raise OneShotError(f"bootstrap: no calibration from {n} frame(s): the detections do not determine the pose "
                               f"(calibrator: {last.reason}); record more frames with several objects seen by both sensors")
        report = session.adapt(steps=steps, lr=lr, holdout=holdout, min_holdout=MIN_HELDOUT_FRAMES if holdout > 0 else 0,
                               progress=on_step)
        if not report.trained:
            raise OneShotError(f"bootstrap: training did not produce weights ({report.message}); nothing installed")
        threshold = choose_threshold(session.matcher, kept, session.calibration)
        if threshold is not None:  # saved with the weights (model config); match() uses it by default
            session.matcher.config["match_threshold"] = threshold.threshold
        held = [k for k in report.heldout_frames if k < len(kept)]
        site_default = choose_site_default(session.matcher, kept, session.calibration, holdout=holdout, held=held)
        if site_default is not None:  # saved with the weights; match(geometry="auto") projects when "geometry"
            session.matcher.config["site_default"] = dataclasses.asdict(site_default)
        heldout = check_heldout(session, report.heldout_frames, calib_config=calib_config) if report.heldout_frames \
            else None
        paths: dict[str, Path] = {}
        if out_dir is not None:
            paths.update({f"out_{k}": v for k, v in session.save(out_dir).items()})
        if install:
            paths.update(session.save_site(site))
        return BootstrapResult(site=site, model=model, init=init_desc, n_frames=n, calibration=session.calibration,
                               adapt=report, paths=paths, elapsed_s=time.perf_counter() - t0, matcher=session.matcher,
                               threshold=threshold, site_default=site_default, heldout=heldout)
