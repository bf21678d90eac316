"""``python -m equipose.train.widen``: the old name of ``equipose.train.network.widen`` (same functions and command
line; both names work)."""
import sys

from equipose.train.network.widen import *  # noqa: F401,F403
from equipose.train.network.widen import __all__, main  # noqa: F401

if __name__ == "__main__":
    sys.exit(main())
