"""``python -m tuners``: the umbrella command ``gripper`` (:mod:`tuners.commands`)."""

import sys

from tuners.commands import main

if __name__ == "__main__":
    sys.exit(main())
