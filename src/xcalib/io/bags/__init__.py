"""ROS 1 ``.bag``, ROS 2 ``.db3`` and ``.mcap`` without ROS: read as frames, write from frames.

* :func:`bag_info` — topics, types, counts, rates.
* :class:`BagFrames` — one LiDAR + one camera paired by header stamp (``report``: what was
  dropped and why); registered as the frame source ``bag`` (``read_frames("x.mcap", camera=...)``).
* :func:`write_bag` — frames -> any of the three containers (read back equal).
"""

from __future__ import annotations

from .reader import (  # noqa: F401
    BAG_SUFFIXES,
    META_TOPIC,
    BagCamera,
    BagFrames,
    BagInfo,
    BagTopic,
    Dropped,
    PairingReport,
    bag_cameras,
    bag_info,
    is_bag,
    pair_by_time,
    recorded_stamp_ns,
    rectified_from,
)
from .writer import topic_name, write_bag  # noqa: F401

__all__ = ["BAG_SUFFIXES", "META_TOPIC", "BagCamera", "BagFrames", "BagInfo", "BagTopic", "Dropped", "PairingReport",
           "bag_cameras", "bag_info", "is_bag", "pair_by_time", "recorded_stamp_ns", "rectified_from", "topic_name",
           "write_bag"]


def _register() -> None:
    from ..sources import register_source

    register_source("bag", is_bag, BagFrames,
                    description="ROS 1 .bag, ROS 2 .db3 / bag folder, .mcap (camera=, lidar=, tolerance_s=)",
                    priority=25)


_register()
