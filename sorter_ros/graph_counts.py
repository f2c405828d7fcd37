"""
A topic's publishers counted once per ROS Context and simulated second, for every node of it.

The cell and the controller each check who publishes ``/clock`` at their diagnostics
period (two publishers are two times: a clock fault). rmw answers a count by walking
every endpoint of the process's graph, and in a line run in one process the graph is
large and the askers many: 24 stations and their 24 programs, some 3 900 endpoints,
each asking at its diagnostics period (the programs' on the wall clock). Those walks
took 1.7 % of a 24-station line's main thread, 0.4 % once shared (py-spy,
docs/benchmarks.md). Every node of one Context sees one graph, so the first to ask in
a simulated second counts and the others of that second take its answer: a count is
at most one simulated second old. While simulated time stands still (a paused
lock-step cell) it is not counted again.
"""

from __future__ import annotations

import weakref

WINDOW_NS = 10**9  # the simulated time a count serves [ns]

# topic -> (the Context it was counted in, its window of simulated time, the count)
_last: dict[str, tuple] = {}


def publisher_count(node, topic: str, t_ns: int) -> int:
    """
    Return how many publishers ``topic`` has, counted at most once per Context and window.

    Parameters
    ----------
    node : rclpy.node.Node
        The node asking; its Context is the graph counted.
    topic : str
        The fully qualified topic (``/clock``).
    t_ns : int
        The simulated time of the question [ns]; the count serves the rest of its window
        (``WINDOW_NS``). Time that stands still is one window.

    Returns
    -------
    int
        The count.

    """
    window = t_ns // WINDOW_NS
    last = _last.get(topic)
    if last is not None and last[0]() is node.context and last[1] == window:
        return last[2]
    n = node.count_publishers(topic)
    _last[topic] = (weakref.ref(node.context), window, n)
    return n
