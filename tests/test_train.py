"""Trainer, metrics, resume, single-detection frames, 2-process torchrun."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from _matching_frames import TINY, make_frame, make_frames
from xcalib.engine.matcher import Matcher
from xcalib.engine.metrics import MetricsAccumulator, latency_stats, row_ranks
from xcalib.engine.trainer import XCALIB_RECIPE, matching_loss, train

TESTS = Path(__file__).resolve().parent


def test_row_ranks_multi_positive_and_pessimistic_ties():
    s = np.array([[0.9, 0.5, 0.1], [0.2, 0.2, 0.6], [0.1, 0.1, 0.1], [0.3, 0.2, 0.1]])
    gt = np.array([[0, 1, 0], [1, 0, 1], [1, 0, 0], [0, 0, 0]], bool)
    assert row_ranks(s, gt).tolist() == [2, 1, 3]  # row 3 has no positive: not counted
    acc = MetricsAccumulator()
    acc.add(s, gt, 2.0)
    acc.add(np.eye(2), np.eye(2, dtype=bool), 4.0)
    m = acc.result()
    assert m.n_cameras_with_match == 5 and m.n_frames == 2
    assert m.top1 == pytest.approx(3 / 5) and m.top3 == 1.0
    assert m.mrr == pytest.approx((0.5 + 1 + 1 / 3 + 2) / 5)
    assert m.frame_top1 == pytest.approx((1 / 3 + 1) / 2)
    assert latency_stats([1, 2, 3])["latency_ms_p50"] == 2.0
    with pytest.raises(ValueError, match="same"):
        row_ranks(np.zeros((2, 2)), np.zeros((2, 3), bool))


def test_loss_uses_every_positive_and_masks_other_frames():
    from xcalib.models.base import TrainLogits

    class B:  # two frames: row 0 with columns 0,1,2 | row 1 with column 3
        seg_2d, seg_3d = torch.tensor([0, 1]), torch.tensor([0, 0, 0, 1])

        def same_frame(self):
            return self.seg_2d[:, None] == self.seg_3d[None]

    gt = torch.tensor([[True, True, False, False], [False, False, False, True]])
    second = torch.tensor([[-5.0, 5.0, 0.0, 99.0], [0.0, 0.0, 0.0, 1.0]])  # 99: other frame, masked
    wrong = torch.tensor([[-5.0, -5.0, 5.0, 99.0], [0.0, 0.0, 0.0, 1.0]])
    l_second = matching_loss([TrainLogits(second)], B(), gt)
    l_wrong = matching_loss([TrainLogits(wrong)], B(), gt)
    # the second positive scoring highest is right (a first-positive-only target would cost ~10)
    assert l_second < 0.05 and l_wrong > 2.0
    l_bce = matching_loss([TrainLogits(second, "logit")], B(), gt)
    assert l_bce > l_second  # the BCE term is added for "logit" outputs


def test_fastmatch_learns_and_resumes(tmp_path):
    torch.manual_seed(0)
    tr, va = make_frames(16, 1), make_frames(6, 2)
    before = Matcher("fastmatch", TINY["fastmatch"], device="cpu", allow_random=True)
    acc0 = MetricsAccumulator()
    for f in va:
        acc0.add(before.match_frame(f).full_similarity(f.num_2d, f.num_3d, -9), f.match_matrix)
    best = train("fastmatch", tr, va, config=TINY["fastmatch"], **XCALIB_RECIPE.kwargs(epochs=6, warmup_epochs=1, lr=3e-3),
                 output_dir=tmp_path / "run", progress=False, seed=0)
    hist = json.loads((tmp_path / "run" / "history.json").read_text())
    assert len(hist) == 6 and best.name == "best.pth" and (tmp_path / "run" / "best.yaml").exists()
    m = Matcher.from_pretrained("fastmatch", weights=best, device="cpu")
    acc = MetricsAccumulator()
    for f in va:
        acc.add(m.match_frame(f).full_similarity(f.num_2d, f.num_3d, -9), f.match_matrix)
    assert acc.result().mrr > acc0.result().mrr + 0.1
    assert acc.result().mrr == pytest.approx(max(h["val_mrr"] for h in hist), abs=1e-6)
    # resume continues from last.pt to more epochs
    train("fastmatch", tr, va, config=TINY["fastmatch"], **XCALIB_RECIPE.kwargs(epochs=7, warmup_epochs=1, lr=3e-3),
          output_dir=tmp_path / "run", progress=False, seed=0, resume=True)
    hist2 = json.loads((tmp_path / "run" / "history.json").read_text())
    assert [h["epoch"] for h in hist2] == list(range(1, 8)) and hist2[:6] == hist


def test_single_detection_frames_train_crlite_and_matcher_train(tmp_path):
    tr = [make_frame(i, n_obj=1) for i in range(3)]
    for f in tr:  # one 2D box and one 3D box per frame
        f.bboxes_3d, f.match_matrix = f.bboxes_3d[f.match_matrix[0]], np.ones((1, 1), bool)
    m = Matcher("crlite", TINY["crlite"], device="cpu", allow_random=True)
    best = m.train(tr, tr[:1], output_dir=tmp_path, epochs=2, warmup_epochs=0, frames_per_batch=1,
                   progress=False)
    assert best.exists() and not m.model.training
    r = m.match_frame(tr[0])
    assert r.similarity.shape == (1, 1)


def test_no_usable_frames_is_a_clear_error(tmp_path):
    f = make_frame(0)
    f.match_matrix = np.zeros_like(f.match_matrix)
    with pytest.raises(ValueError, match="no usable training frame"):
        train("fastmatch", [f], None, config=TINY["fastmatch"], epochs=1, output_dir=tmp_path, progress=False)


def test_an_empty_training_cache_is_named(tmp_path):
    """`xcalib synth ... --train 0` writes an empty train.h5: training on it names the file and
    says it is empty, not that its frames lack positives."""
    from xcalib.io.hdf5 import write_cache

    write_cache(tmp_path / "train.h5", [], camera_names=["camera"])
    empty = tmp_path / "train.h5"
    with pytest.raises(ValueError, match=r"train\.h5: no training frames \(an empty cache\)"):
        train("fastmatch", empty, None, config=TINY["fastmatch"], epochs=1, output_dir=tmp_path / "run", progress=False)


def test_torchrun_two_cpu_processes(tmp_path):
    script = tmp_path / "ddp_train.py"
    script.write_text(textwrap.dedent(f"""
        import sys, json
        sys.path.insert(0, {str(TESTS)!r})
        import torch
        torch.set_num_threads(1)
        import torch.distributed as dist
        from _matching_frames import TINY, make_frames
        from xcalib.engine.trainer import shutdown_distributed, train
        best = train("crlite", make_frames(4, 1, n_obj=2), make_frames(2, 2, n_obj=2), config=TINY["crlite"],
                     epochs=2, warmup_epochs=0, frames_per_batch=1, output_dir={str(tmp_path / 'run')!r},
                     device="cpu", progress=False)
        open({str(tmp_path)!r} + f"/rank{{dist.get_rank()}}.json", "w").write(
            json.dumps([dist.get_world_size(), str(best)]))
        shutdown_distributed()
        assert not dist.is_initialized()
        sys.stdout.flush(); sys.stderr.flush()
        import os; os._exit(0)  # skip interpreter finalisation: torch's gloo threads may abort there (torch bug)
    """))
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2",
                           str(script)], capture_output=True, text=True, timeout=240, env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    for r in (0, 1):
        assert json.loads((tmp_path / f"rank{r}.json").read_text())[0] == 2
    hist = json.loads((tmp_path / "run" / "history.json").read_text())
    assert len(hist) == 2 and np.isfinite(hist[-1]["train_loss_mean"])
    Matcher.from_pretrained("crlite", weights=tmp_path / "run" / "best.pth", device="cpu")


def test_negative_sampling_keeps_every_matched_3d_box():
    from xcalib.data.crops import CropConfig
    from xcalib.engine.trainer import prepare_samples

    f = make_frame(9, n_obj=3)
    (s,), skipped = prepare_samples([f], CropConfig(point_cloud_size=8))
    fi, gt = s.draw(8, np.random.default_rng(0), 0.0, max_3d=3)
    assert skipped == 0 and fi.num_3d == 3 and gt.shape == (3, 3) and gt.any(axis=0).all()
    fi, gt = s.draw(8, np.random.default_rng(0), 0.05, max_3d=None)
    assert fi.num_3d == 4 and not np.allclose(fi.boxes_2d, s.boxes_2d)  # jittered boxes
