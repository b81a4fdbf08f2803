"""placecell-eval: experiments run through the daemon's own pipeline on the simulated robot."""
