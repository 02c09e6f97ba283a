"""``python -m tuners.sysid``: identification's command line (:mod:`.commands`)."""

import sys

from tuners.sysid import main

if __name__ == "__main__":
    sys.exit(main())
