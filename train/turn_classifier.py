"""``python -m equipose.train.turn_classifier``: the old name of ``equipose.train.fitting.turn_classifier`` (same
functions and command line; both names work)."""
import sys

from equipose.train.fitting.turn_classifier import *  # noqa: F401,F403
from equipose.train.fitting.turn_classifier import __all__, main  # noqa: F401

if __name__ == "__main__":
    sys.exit(main())
