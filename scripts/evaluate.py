"""``python scripts/evaluate.py DATA_DIR [--json] [--out DIR]``: the same as ``torch4dtree evaluate``."""

import sys

from torch4dtree.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["evaluate", *sys.argv[1:]]))
