"""``python -m equipose.train.averaging``: the old name of ``equipose.train.lanes.averaging`` (same functions and
command line; both names work)."""
import sys

from equipose.train.lanes.averaging import *  # noqa: F401,F403
from equipose.train.lanes.averaging import __all__, main  # noqa: F401

if __name__ == "__main__":
    sys.exit(main())
