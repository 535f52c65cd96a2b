# Runs first at every reset. Keep it short: main.py starts the stage.
import gc

gc.collect()
