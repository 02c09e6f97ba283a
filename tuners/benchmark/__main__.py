"""``python -m tuners.benchmark`` (:mod:`tuners.benchmark.command`)."""

import sys

from tuners.benchmark.command import main

sys.exit(main())
