"""Graph feeds (numpy, torch-free): the named inputs of the image / LiDAR embedding graphs of
one frame and of the pair graph, shared by the exporter and the ONNX Runtime matcher."""

from __future__ import annotations

import numpy as np

from ..data.crops import FrameInputs

__all__ = ["IMAGE_INPUTS", "LIDAR_INPUTS", "frame_feeds", "pair_feeds"]

IMAGE_INPUTS = ("image_crops", "boxes_2d", "image_wh")
LIDAR_INPUTS = ("lidar_crops", "boxes_3d", "point_counts")


def frame_feeds(inputs: FrameInputs) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(image feeds, LiDAR feeds): image_crops [N,3,S,S], boxes_2d [N,4] px, image_wh [N,2] px;
    lidar_crops [M,P,3] box-frame m, boxes_3d [M,7] box7 m, point_counts [M] (all float32)."""
    wh = np.tile(np.asarray(inputs.image_size, np.float32), (inputs.num_2d, 1))
    img = {"image_crops": np.ascontiguousarray(inputs.crops_2d, np.float32),
           "boxes_2d": np.ascontiguousarray(inputs.boxes_2d, np.float32).reshape(-1, 4),
           "image_wh": wh.reshape(-1, 2)}
    lid = {"lidar_crops": np.ascontiguousarray(inputs.crops_3d, np.float32),
           "boxes_3d": np.ascontiguousarray(inputs.boxes_3d, np.float32).reshape(-1, 7),
           "point_counts": np.asarray(inputs.point_counts, np.float32).reshape(-1)}
    return img, lid


def pair_feeds(img_out: dict[str, np.ndarray], lid_out: dict[str, np.ndarray], rows: np.ndarray,
               cols: np.ndarray) -> dict[str, np.ndarray]:
    """Pair-graph feeds: every image output gathered at ``rows``, every LiDAR output at ``cols``."""
    feeds = {k: np.ascontiguousarray(v[rows]) for k, v in img_out.items()}
    feeds.update({k: np.ascontiguousarray(v[cols]) for k, v in lid_out.items()})
    return feeds
