"""``python -m tuners.optuna`` (:mod:`tuners.optuna.command`)."""

import sys

from tuners.optuna.command import main

sys.exit(main())
