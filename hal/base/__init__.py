"""Mobile base backends: sim, replay (MCAP), xr4000-serial, xr4000-can."""
