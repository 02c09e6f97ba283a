"""``python -m tuners.rl`` (:mod:`tuners.rl.command`)."""

import sys

from tuners.rl.command import main

sys.exit(main())
