"""Mobile base backends: sim, replay (MCAP), xr4000-serial, xr4000-can, ros2 (rmw_zenoh)."""
