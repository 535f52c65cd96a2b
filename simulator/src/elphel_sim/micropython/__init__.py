"""micropython."""
