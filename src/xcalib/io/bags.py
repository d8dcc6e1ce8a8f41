"""ROS 1 / ROS 2 bags and MCAP as frame sources (placeholder; filled in below)."""
