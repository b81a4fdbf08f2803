"""The map file: the topological map in one SQLite file, and its folder export (design §6)."""
