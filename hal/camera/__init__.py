"""Camera backends: sim, replay (MCAP), v4l2, libcamera."""
