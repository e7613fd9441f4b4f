"""``python -m fabric_optics.cli.simulate``: the ``simulate`` console script."""

import sys

from fabric_optics.cli.simulate import main

sys.exit(main())
