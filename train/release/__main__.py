"""``python -m equipose.train.release MODEL``: see ``equipose.train.release.steps``."""
import sys

from equipose.train.release.steps import main

if __name__ == "__main__":
    sys.exit(main())
