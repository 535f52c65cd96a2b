# Runs after boot.py. Ctrl-C within the first two seconds (mpremote sends it when it
# connects) leaves the REPL usable instead of starting the stage.
import time

time.sleep_ms(2000)

import stage_main  # noqa: E402

stage_main.run()
