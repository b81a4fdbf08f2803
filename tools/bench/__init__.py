"""placecell-bench: speed figures of the pipeline, medians of repeated runs."""
