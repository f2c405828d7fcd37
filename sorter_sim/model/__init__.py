"""
The pure model of the cell: what both nodes share, and nothing that runs or talks.

``core`` holds the numerics (friction laws, footprint geometry, wrenches, the
integrators and the cell's compiled period kernels); ``description`` the cell's
quantities and their limits; ``io_map`` the I/O image a PLC sees; ``build`` the
three-zone cell and its friction laws built from plain numbers. Nothing here
imports ROS, YAML or the runtime (import-linter's layers contract checks it).
"""
