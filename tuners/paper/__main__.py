"""``python -m tuners.paper``: reproduce the paper's tables and figures (:mod:`.command`)."""

import sys

from tuners.paper.command import main

if __name__ == "__main__":
    sys.exit(main())
