"""
A process that records as the nodes do, one message every 2 ms stamped with the wall clock.

``python recording_driver.py OUT.mcap`` opens ``OUT.mcap`` with the nodes' recorder (its
writer process and all) and writes ``std_msgs/String`` messages numbered 0, 1, 2 ... on
``/counter``, each stamped with the wall-clock time it was handed over, until killed:
what a file killed any way still holds is then read against the time of the kill.
"""

import sys
import time

from std_msgs.msg import String

from sorter_ros.recording import open_recorder


def main(path: str) -> None:
    rec = open_recorder(path, on_failure=lambda text: print(text, file=sys.stderr, flush=True))
    print(rec._proc.pid, flush=True)  # the writer's pid, for the test to kill
    n = 0
    while True:
        rec.write('/counter', String(data=str(n)), time.time_ns())
        n += 1
        time.sleep(0.002)


if __name__ == '__main__':
    main(sys.argv[1])
