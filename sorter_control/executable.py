"""
The ``controller_node`` and ``wcs_node`` executables.

Light on purpose: the console script imports only this and ``sorter_ros.env``, so
the stop signals are caught before the node's modules load (``start_node``).
"""

from sorter_ros.env import start_node


def main(args=None) -> None:
    """
    Entry point of ``controller_node`` (``ros2 run sorter_cell controller_node``).

    Parameters
    ----------
    args : list of str or argparse.Namespace
        The command line, or the parsed arguments.

    """
    start_node("sorter_control.node", args)


def main_wcs(args=None) -> None:
    """
    Entry point of ``wcs_node`` (``ros2 run sorter_cell wcs_node``), the line's warehouse node.

    Parameters
    ----------
    args : list of str
        The command line.

    """
    start_node("sorter_control.wcs_node", args)
