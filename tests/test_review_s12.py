"""Session 12's review (R) of the merged change: what it found wrong, each with a test that fails
on the code before the fix. The worker pool's ``later`` queue refuses a task once the pool is
closed (it would wait forever); one camera of a multi-camera frame keeps the detector scores of
its own 2D boxes (the whole frame's do not line up with them and were dropped)."""

from __future__ import annotations

import multiprocessing as mp

import numpy as np
import pytest

from xcalib.calib.parallel import WorkerPool
from xcalib.types import OWN_DETECTIONS, Frame, FrameDetections

needs_fork = pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="no fork start method")


def _square(x):
    return x * x


@needs_fork
def test_a_later_task_submitted_as_the_pool_closes_is_refused_not_left_waiting():
    """``submit(later=True)`` checked the pool open (``executor()``) and then queued the task: a
    ``close`` in between had already given the queue up and stopped the feeder, so the task's
    future never completed. Now the queueing itself refuses a closed pool."""
    pool = WorkerPool(2)
    opened = pool.executor

    def closing_meanwhile():  # the pool is closed (on another thread) right after the check
        ex = opened()
        pool.close()
        return ex

    pool.executor = closing_meanwhile
    with pytest.raises(RuntimeError, match="closed"):
        pool.submit(_square, 3, later=True)
    assert not pool._later and pool._feeder is None
    assert mp.active_children() == []


def test_one_camera_of_a_frame_keeps_the_scores_of_its_own_boxes():
    from xcalib.calib.inputs import input_scores
    from xcalib.io.sources import camera_view

    b2 = np.array([[0, 0, 10, 10], [5, 5, 20, 20], [1, 1, 9, 9]], np.float32)
    made = FrameDetections(OWN_DETECTIONS, (0.9, 0.4, 0.7), ("car", "truck", "car"), "det.onnx", "moving")
    frame = Frame(np.zeros((48, 64, 3), np.uint8), np.zeros((5, 3), np.float32), b2,
                  np.zeros((0, 7), np.float32), camera_name="front", camera_per_det=["front", "left", "front"],
                  images={"front": np.zeros((48, 64, 3), np.uint8), "left": np.zeros((48, 64, 3), np.uint8)},
                  detections=made)
    front, left = camera_view(frame, "front"), camera_view(frame, "left")
    assert front.detections == FrameDetections(OWN_DETECTIONS, (0.9, 0.7), ("car", "car"), "det.onnx", "moving")
    assert left.detections.scores_2d == (0.4,) and left.detections.classes_2d == ("truck",)
    assert np.array_equal(input_scores(front.meta, front.num_2d, 0, front.detections), [0.9, 0.7])
    # scores that do not line up with the frame's boxes are left as they are (input_scores names them)
    odd = camera_view(Frame(frame.image, frame.point_cloud, b2, frame.bboxes_3d, camera_per_det=frame.camera_per_det,
                            images=frame.images, camera_name="front",
                            detections=FrameDetections("x", (0.5,))), "front")
    assert odd.detections == FrameDetections("x", (0.5,))
    assert camera_view(Frame(frame.image, frame.point_cloud, b2, frame.bboxes_3d), "").detections is None


def test_boxes_source_survives_calibration_json(tmp_path):
    """``CalibrationResult.boxes_source`` replaced the plain advice's read of
    ``meta["detection_coverage"]`` but was not written to calibration.json: a refused result read
    back gave the advice to change the intrinsics, which the own-detections advice warns against."""
    from xcalib.calib.diagnostics import CalibDiagnostics
    from xcalib.calib.result import CalibrationResult
    from xcalib.viz.advice import plain_advice

    res = CalibrationResult(success=False, message="misfit", diagnostics=CalibDiagnostics(refusal="misfit_focal_length"),
                            meta={"detection_coverage": {"share": 0.9}}, boxes_source=OWN_DETECTIONS)
    back = CalibrationResult.load(res.save(tmp_path / "calibration.json"))
    assert back.boxes_source == OWN_DETECTIONS and plain_advice(back) == plain_advice(res)
    assert "label-free" in plain_advice(back)[0]
    plain = CalibrationResult(success=False, message="misfit")
    assert "boxes_source" not in plain.to_dict()  # other results' files unchanged
    assert CalibrationResult.from_dict(plain.to_dict()).boxes_source == ""


#: released by the test (inherited by the forked workers: made before the pool)
_GATE = mp.get_context("fork").Event() if "fork" in mp.get_all_start_methods() else None


def _blocked(x):
    assert _GATE.wait(120), "the gate was never opened"
    return x


@needs_fork
def test_closing_a_deferred_does_not_wait_for_its_cancelled_later_calls():
    """``Deferred.close`` waited for its cancelled calls too; a cancelled ``later`` call counts as
    done (``concurrent.futures.wait``) only once the pool's feeder reaches it, i.e. once a process
    is idle: the close waited for unrelated tasks to end."""
    import threading

    from xcalib.calib.parallel import Deferred

    _GATE.clear()
    with WorkerPool(2) as pool:
        busy = [pool.submit(_blocked, k) for k in range(2)]  # both processes held until the gate opens
        d = Deferred([(_square, (2,)), (_square, (3,))], 2, later=(0, 1))
        closing = threading.Thread(target=d.close)
        closing.start()
        closing.join(60)
        done_while_busy = not closing.is_alive()
        _GATE.set()
        closing.join(120)
        assert done_while_busy, "Deferred.close waited for the pool's other tasks"
        assert [f.result(timeout=120) for f in busy] == [0, 1]
