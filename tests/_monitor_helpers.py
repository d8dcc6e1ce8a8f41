"""Helpers of the monitor tests: a synthetic site's stream with a turn injected part-way."""

from __future__ import annotations

from dataclasses import replace

import numpy as np


def turned_stream(n_frames: int = 150, turn_from: int = 90, turn_deg: float = 0.3):
    """(calibration, frames): site 3's stream of ``n_frames`` (3D boxes exact, no images or clouds) with a
    ``turn_deg`` turn about x injected from frame ``turn_from`` on, and the site's true calibration."""
    from xcalib.calib.result import CalibrationResult
    from xcalib.data.synth import iter_frames, sample_site
    from xcalib.monitor.inject import inject_change

    site = sample_site(3, n_objects=(15, 30))
    T = site.T_cam_lidar
    cal = CalibrationResult(success=True, intrinsics=site.intrinsics_given, rotation=T[:3, :3], translation=T[:3, 3],
                            rotation_std_deg=np.full(3, 0.05), translation_std_m=np.full(3, 0.02),
                            camera_name=site.camera_name, image_size=(site.width, site.height))
    frames = [replace(f, bboxes_3d=np.asarray(f.meta["box7"], dtype=np.float32))
              for f in iter_frames(site, n_frames, 0, render_images=False, lidar=False)]
    frames = [inject_change(f, cal, [turn_deg, 0, 0], [0, 0, 0]) if i >= turn_from else f for i, f in enumerate(frames)]
    return cal, frames
