"""Sub-pixel bursts: the plan (plan.py), the burst format (io.py), the capture (capture.py).

``cli.py`` is ``elphel burst plan|capture``; nothing here imports it.
"""
