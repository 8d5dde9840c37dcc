"""``python scripts/fit.py DATASET_DIR --config configs/X.json --out RUN_DIR``: the same as ``torch4dtree fit``."""

import sys

from torch4dtree.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["fit", *sys.argv[1:]]))
