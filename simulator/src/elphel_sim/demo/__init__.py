"""`make demo`: the main job on the simulator, end to end (`python -m elphel_sim.demo`).

`run` is the whole job and its command line, `rig` the simulated rig and the user's tools
the steps go through, `burst`, `calib` and `depth` the burst, quad calibration and
quad-burst steps, `report` the simulator's truth on the fused grid and the pictures.
"""
