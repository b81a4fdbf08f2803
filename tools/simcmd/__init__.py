"""Subcommands of placecell-sim."""
