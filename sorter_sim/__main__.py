"""``python -m sorter_sim`` is the ``sorter`` command."""

import sys

from .cli import main

sys.exit(main())
