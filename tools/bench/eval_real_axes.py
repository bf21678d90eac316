"""Real-data check of predicted symmetry axes against the table normal (mOSD scenes); see ``equipose.eval.real_axes``.

Usage: python tools/bench/eval_real_axes.py [--models cup-tabletop bowl-tabletop can-tabletop] [--data DIR] [...]
"""
import sys

from equipose.eval.real_axes import main

if __name__ == "__main__":
    sys.exit(main())
