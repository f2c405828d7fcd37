"""
The ``sim_node`` executable.

Light on purpose: the console script imports only this and ``sorter_ros.env``, so
the stop signals are caught before the node's modules load (``start_node``).
"""

from sorter_ros.env import start_node


def main(args=None) -> None:
    """
    Run ``sim_node`` (``ros2 run sorter_cell sim_node``).

    Parameters
    ----------
    args : list of str, optional
        The command line (default: the process's).

    """
    start_node('sorter_sim.frontends.node', args)


def main_line(args=None) -> None:
    """
    Run ``line_node`` (``ros2 run sorter_cell line_node``), a line of stations.

    Parameters
    ----------
    args : list of str, optional
        The command line (default: the process's).

    """
    start_node('sorter_sim.frontends.line_node', args)
