"""The built-in simulated robot and world: rendered mirror camera, drifting odometry."""
