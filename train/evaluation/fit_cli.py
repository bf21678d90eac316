"""The command line the fits on rendered tabletop views share (``confidence``, ``centre``, ``rest_side``): the model
file, how many views from which seed, the data root, ``--write`` (store the fit in the model file and its int8
sibling) and ``--json`` (write the rows)."""
from __future__ import annotations

import argparse

__all__ = ["fit_parser"]


def fit_parser(doc: str, views: int = 200, seed: int = 0,
               write_help: str = "store the fit in the model file (and its .int8 sibling)") -> argparse.ArgumentParser:
    """An ``ArgumentParser`` described by ``doc``'s first line with the shared options; each fit adds its own."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--views", type=int, default=views, help="rendered views")
    ap.add_argument("--seed", type=int, default=seed)
    ap.add_argument("--data-root", dest="data_root")
    ap.add_argument("--write", action="store_true", help=write_help)
    ap.add_argument("--json", help="write the summary and every row here")
    return ap
