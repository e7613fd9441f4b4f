"""``python -m gonio.mock ...`` = ``gonio mock ...``."""

import sys

from gonio.mock.cli import main

sys.exit(main(sys.argv[1:]))
