"""Poses, sigmas and verdicts of a few calibrations as JSON, to check that a refactor changed none.

Cases: the demo site (``sample_site(0)``, 20 frames, traffic seed 5) with the default config and
with ``refine_intrinsics="focal+center"``; the realism case ``time_offset_0.1s`` with
``time_offset="estimate"``; the A9 sample (``../shared/data/a9_sample``, skipped when absent); with
``--realism K``, also every registered realism condition on its first ``K`` identifiable site seeds
(default config, as ``benchmarks/bench_calibration_realism.py`` runs them).

Usage (run once per tree, then compare)::

    PYTHONPATH=<tree>/src python scripts/pose_identity.py run before.json
    PYTHONPATH=<tree>/src python scripts/pose_identity.py run after.json [--realism K]
    python scripts/pose_identity.py compare before.json after.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

A9 = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "a9_sample"


def _summary(res) -> dict:
    import numpy as np

    return {"success": bool(res.success), "message": res.message, "n_inliers": int(res.n_inliers),
            "R": None if res.rotation is None else np.asarray(res.rotation, float).tolist(),
            "t": None if res.translation is None else np.asarray(res.translation, float).tolist(),
            "rotation_std_deg": np.asarray(res.rotation_std_deg, float).tolist(),
            "translation_std_m": np.asarray(res.translation_std_m, float).tolist(),
            "time_offset_s": getattr(res, "time_offset_s", None),
            "intrinsics": None if res.intrinsics is None else res.intrinsics.to_dict()}


def run(out: Path, realism: int = 0) -> None:
    from xcalib.calib.api import calibrate
    from xcalib.calib.config import CalibConfig
    from xcalib.data.synth import generate_frames, sample_site
    from xcalib.data.synth.realism import make_realism_case

    frames = generate_frames(sample_site(0, "roadside"), 20, seed=5)
    cases = {"demo": calibrate(frames),
             "demo_focal_center": calibrate(frames, config=CalibConfig(refine_intrinsics="focal+center"))}
    case = make_realism_case("time_offset_0.1s", 0)
    cases["time_offset_0.1s"] = calibrate(list(case.frames), case.intrinsics_given, CalibConfig(time_offset="estimate"))
    if A9.is_dir():
        from xcalib.io.sources import open_source

        cases["a9"] = calibrate(list(open_source(A9)))
    if realism:
        import warnings

        from xcalib.data.synth.realism import REALISM_CONDITIONS, identifiable_site_seeds

        for seed in identifiable_site_seeds(realism):
            for name in REALISM_CONDITIONS:
                case = make_realism_case(name, seed)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    cases[f"realism:{name}:{seed}"] = calibrate(list(case.frames), case.intrinsics_given)
                print(f"realism:{name}:{seed}", cases[f"realism:{name}:{seed}"].success, flush=True)
    result = {k: _summary(v) for k, v in cases.items()}
    out.write_text(json.dumps(result, indent=1))
    print({k: v["success"] for k, v in result.items()})


def compare(a: Path, b: Path) -> int:
    x, y = json.loads(a.read_text()), json.loads(b.read_text())
    bad = 0
    for k in sorted(set(x) | set(y)):
        same = x.get(k) == y.get(k)
        bad += not same
        print(f"{k}: {'identical' if same else 'DIFFERENT'} (success {x.get(k, {}).get('success')} -> "
              f"{y.get(k, {}).get('success')})")
    return 1 if bad else 0


if __name__ == "__main__":
    if len(sys.argv) in (3, 5) and sys.argv[1] == "run" and (len(sys.argv) == 3 or sys.argv[3] == "--realism"):
        run(Path(sys.argv[2]), int(sys.argv[4]) if len(sys.argv) == 5 else 0)
    elif len(sys.argv) == 4 and sys.argv[1] == "compare":
        raise SystemExit(compare(Path(sys.argv[2]), Path(sys.argv[3])))
    else:
        raise SystemExit(__doc__)
