"""Sub-pixel bursts: the plan, the burst format and the capture.

The plan is plan.py; the burst format is manifest.py (``manifest.json``) and io.py (burst
and quad-burst directories); the capture is capture.py (one camera) and quad_capture.py
(a quad camera).

``cli.py`` is ``elphel burst plan|capture``; nothing here imports it.
"""
