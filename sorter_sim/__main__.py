"""``python -m sorter_sim`` is the ``sorter`` command."""

import sys

from sorter_sim.cli import main

sys.exit(main())
