"""``python -m gripper_env.paper``: reproduce the paper's tables and figures (:mod:`.reproduce`)."""

import sys

from gripper_env.paper.reproduce import main

if __name__ == "__main__":
    sys.exit(main())
