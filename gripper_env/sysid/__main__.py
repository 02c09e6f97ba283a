"""``python -m gripper_env.sysid``: identification's command line (:mod:`.commands`)."""

import sys

from gripper_env.sysid.commands import main

if __name__ == "__main__":
    sys.exit(main())
