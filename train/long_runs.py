"""``python -m equipose.train.long_runs``: the old name of ``equipose.train.lanes.long_runs`` (same functions and
command line; both names work)."""
import sys

from equipose.train.lanes.long_runs import *  # noqa: F401,F403
from equipose.train.lanes.long_runs import __all__, main  # noqa: F401

if __name__ == "__main__":
    sys.exit(main())
