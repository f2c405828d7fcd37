"""``python -m sorter_cell VERB ...``: the same as the ``sorter`` command."""

import sys

from sorter_cell.cli import main

sys.exit(main())
