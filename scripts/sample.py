"""``python scripts/sample.py RUN_DIR/model.pt --n N --seed S --out DIR``: the same as ``torch4dtree sample``."""

import sys

from torch4dtree.cli.main import main

if __name__ == "__main__":
    sys.exit(main(["sample", *sys.argv[1:]]))
