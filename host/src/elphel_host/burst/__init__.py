"""Sub-pixel bursts: planning (plan.py) and burst directories (io.py, DESIGN 4.3)."""
