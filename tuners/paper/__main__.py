"""``python -m tuners.paper``: reproduce the paper's tables and figures (:mod:`.reproduce`)."""

import sys

from tuners.paper.reproduce import main

if __name__ == "__main__":
    sys.exit(main())
