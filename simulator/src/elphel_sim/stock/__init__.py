"""The simulated board as a stock Elphel NC393 (Elphel's firmware): parsedit.php and imgsrv.

`elphel-sim up --firmware elphel` serves these instead of elphel-camd: `server` builds
the HTTP applications, `firmware` is the camera behind them, `parsedit` and `imgsrv`
the two wire formats, `compressor` the JP4/JP46/TIFF frames.
"""
