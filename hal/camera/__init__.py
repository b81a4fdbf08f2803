"""Camera backends: sim, replay (MCAP), v4l2, libcamera, ros2 (rmw_zenoh)."""
