"""``python -m torch4dtree.cli``: the console script without installing it."""

import sys

from .main import main

sys.exit(main())
