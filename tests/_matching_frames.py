"""Tiny synthetic camera+LiDAR frames with exact ground truth, for the matcher/trainer tests.

LiDAR frame: x forward, y left, z up (metres). Camera at the LiDAR origin looking along +x.
Objects are boxes of a few classes (class -> size and colour), drawn as filled rectangles;
their points fill the box volume. One extra 3D box lies outside the camera view (no 2D box).
"""

from __future__ import annotations

import numpy as np

from xcalib.types import Frame

W, H, F = 640, 480, 500.0
CLASSES = [((4.0, 1.8, 1.5), (200, 40, 40)), ((1.0, 1.0, 1.8), (40, 200, 40)),
           ((8.0, 2.5, 3.0), (40, 40, 200)), ((2.0, 2.0, 1.0), (220, 220, 40))]


def _project(xyz: np.ndarray) -> np.ndarray:
    """LiDAR points [...,3] -> pixels [...,2] (x forward, y left, z up)."""
    return np.stack([W / 2 - F * xyz[..., 1] / xyz[..., 0], H / 2 - F * xyz[..., 2] / xyz[..., 0]], -1)


def make_frame(seed: int, n_obj: int = 4, points_per_obj: int = 300, shift=(0.0, 0.0)) -> Frame:
    rng = np.random.default_rng(seed)
    image = np.full((H, W, 3), 90, dtype=np.uint8)
    image += rng.integers(0, 20, size=(H, W, 1), dtype=np.uint8)
    b2, b3, pts = [], [], [rng.uniform([-5, -30, -2], [60, 30, 0], size=(400, 3))]
    placed = 0
    while placed < n_obj:
        cls = int(rng.integers(len(CLASSES)))
        dims, colour = CLASSES[cls]
        c = np.array([rng.uniform(12, 40), rng.uniform(-8, 8), dims[2] / 2 - 1.5]) + [*shift, 0]
        corners = c + (np.array(np.meshgrid([-.5, .5], [-.5, .5], [-.5, .5])).reshape(3, -1).T * dims)
        uv = _project(corners)
        x1, y1 = uv.min(0)
        x2, y2 = uv.max(0)
        if x1 < 0 or y1 < 0 or x2 > W or y2 > H or any(np.abs(c[:2] - np.array(b[:2])).max() < 5 for b in b3):
            continue
        image[int(y1):int(y2), int(x1):int(x2)] = colour
        b2.append([x1, y1, x2, y2])
        b3.append([*c, *dims])
        pts.append(c + rng.uniform(-0.5, 0.5, size=(points_per_obj, 3)) * dims)
        placed += 1
    far = np.array([rng.uniform(5, 20), rng.choice([-30.0, 30.0]), -0.5])  # outside the view
    b3.append([*far, 2.0, 2.0, 2.0])
    pts.append(far + rng.uniform(-1, 1, size=(100, 3)))
    mm = np.zeros((n_obj, n_obj + 1), dtype=bool)
    mm[np.arange(n_obj), np.arange(n_obj)] = True
    perm = rng.permutation(n_obj + 1)  # shuffle the 3D numbering
    return Frame(image=image, point_cloud=np.concatenate(pts).astype(np.float32),
                 bboxes_2d=np.array(b2, np.float32), bboxes_3d=np.array(b3, np.float32)[perm],
                 match_matrix=mm[:, perm], frame_key=f"{seed:05d}")


def make_frames(n: int, seed: int = 0, **kw) -> list[Frame]:
    return [make_frame(seed * 1000 + i, **kw) for i in range(n)]


# Tiny configs of every model (fast tests; same code paths as the full-size defaults).
TINY = {
    "fastmatch": {"point_cloud_size": 32, "embed_dim": 16, "geo_dim": 16, "cnn_widths": [8, 8, 16],
                  "pointnet_dims": [16, 16, 32], "pair_hidden": 16},
    "crlite": {"point_cloud_size": 32, "embed_dim": 32, "token_len": 16, "top_k": 3},
    "crlite_2dpe": {"point_cloud_size": 32, "embed_dim": 32, "token_len": 16, "top_k": 3},
    "crlite_vit_exp1": {"crop_size": 16, "point_cloud_size": 32, "embed_dim": 32,
                        "vit": {"patch_size": 8, "embed_dim": 16, "depth": 1, "num_heads": 2}},
    "crlite_vit_exp3": {"crop_size": 16, "point_cloud_size": 32, "embed_dim": 32, "token_len": 16,
                        "vit": {"patch_size": 8, "embed_dim": 16, "depth": 1, "num_heads": 2}},
    "crlite_vit_exp4": {"crop_size": 16, "point_cloud_size": 32, "embed_dim": 32,
                        "vit": {"patch_size": 8, "embed_dim": 16, "depth": 1, "num_heads": 2},
                        "gnn": {"hidden_dim": 16}},
    "calibrefine": {"point_cloud_size": 32, "num_blocks": [1, 1, 1, 1], "base_width": 4, "embed_dim": 32,
                    "token_len": 16, "dense": {"embed_dim": 16, "fusion_dim": 16, "hidden_dim": 8},
                    "pointnet2": [{"npoint": 8, "radius": 0.5, "nsample": 8, "mlp": [8, 16]},
                                  {"npoint": None, "mlp": [16, 32]}]},
}


def small_site():
    """A small roadside synthetic site (640x480, 32 beams) for the one-shot and fusion tests."""
    from xcalib.data.synth import sample_site

    return sample_site(3, width=640, height=480, focal_px=560.0, n_objects=20, lidar_beams=32, lidar_azimuth_steps=512)


def tiny_matcher(seed: int = 0, model: str = "fastmatch"):
    """A ``Matcher`` with a seeded, untrained TINY model on the CPU."""
    import torch

    from xcalib.engine.matcher import Matcher
    from xcalib.models import create_model

    torch.manual_seed(seed)
    return Matcher(create_model(model, TINY[model]), device="cpu")


def states_equal(a, b) -> bool:
    """Same state-dict keys and bit-identical tensors (two ``torch.nn.Module``)."""
    import torch

    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)
