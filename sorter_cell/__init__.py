"""The whole cell: the ``sorter`` command line and the demo that starts both nodes."""
