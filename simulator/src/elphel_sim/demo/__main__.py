"""`python -m elphel_sim.demo`: run the demo (see `elphel_sim.demo.run`)."""

import sys

from elphel_sim.demo.run import main

sys.exit(main())
