"""``python -m tuners.classical`` (:mod:`tuners.classical.command`)."""

import sys

from tuners.classical.command import main

sys.exit(main())
