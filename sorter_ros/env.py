"""
ROS environment defaults and config lookup shared by the entry points.

This module imports nothing from ROS at module level, so the ROS-free parts of
the project (and their tests) can use it freely.

Network: left alone, Fast DDS announces every participant by multicast on every
network interface, so a simulated cell started on a laptop in an office or lab
network talks to (and is disturbed by) any other ROS 2 graph on the same
subnet. The entry points therefore call :func:`apply_ros_env_defaults` before
``rclpy.init()``, which keeps discovery on this host unless the user chose
otherwise:

* ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` is the default set here; a value
  already in the environment always wins.
* To reach nodes on other machines, set ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``
  (or ``SYSTEM_DEFAULT`` for the middleware's own default), and pick a
  ``ROS_DOMAIN_ID`` (0-232, shared by all nodes that should see each other)
  to keep separate graphs apart.
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE_NAME = 'sorter_cell'

DISCOVERY_RANGE_VAR = 'ROS_AUTOMATIC_DISCOVERY_RANGE'
DEFAULT_DISCOVERY_RANGE = 'LOCALHOST'

# config/ of a checkout (or an editable install): the repository root is the
# parent of this package.
SOURCE_CONFIG_DIR = Path(__file__).resolve().parents[1] / 'config'


def apply_ros_env_defaults() -> None:
    """
    Restrict DDS discovery to this host unless the user set a range.

    Call before ``rclpy.init()``; the setting is read when the context starts.
    A variable set but empty counts as unset: rmw would read an empty range as its
    own default (discovery on every interface), which nobody chooses by leaving it empty.
    """
    if not os.environ.get(DISCOVERY_RANGE_VAR, '').strip():
        os.environ[DISCOVERY_RANGE_VAR] = DEFAULT_DISCOVERY_RANGE


def find_config_dir() -> Path:
    """
    Return the directory holding ``cell.yaml`` and ``scenes/``.

    Looks first for ``config/`` in the source tree next to this package (a
    checkout or an editable install), then in the installed package share
    directory (``share/sorter_cell/config`` of a colcon/ament install).
    """
    if SOURCE_CONFIG_DIR.is_dir():
        return SOURCE_CONFIG_DIR

    share_config = None
    try:
        from ament_index_python.packages import get_package_share_directory
    except ImportError:
        pass
    else:
        try:
            share_config = Path(get_package_share_directory(PACKAGE_NAME)) / 'config'
        except (LookupError, OSError, ValueError):
            # PackageNotFoundError is a LookupError; OSError: no AMENT_PREFIX_PATH.
            pass
    if share_config is not None and share_config.is_dir():
        return share_config

    share_where = share_config or f'share/{PACKAGE_NAME}/config via the ament index'
    raise FileNotFoundError(
        f'sorter_cell config directory not found; looked in {SOURCE_CONFIG_DIR} '
        f'and {share_where}. Run from a checkout of the repository, or build '
        f'and source the ROS 2 workspace that installs sorter_cell.'
    )


def run_node(make_node, prog: str, config_errors: tuple = (ValueError,), args=None) -> None:
    """
    Run a node as every executable of this package does (ros2/demos talker style).

    Applies the discovery default, initialises rclpy, spins ``make_node()`` and
    tears down in ``finally``. A configuration error raised while the node is
    built (one of ``config_errors``) is printed as one line and exits with code 2.
    """
    import sys

    import rclpy
    from rclpy.executors import ExternalShutdownException

    apply_ros_env_defaults()
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = make_node()
        rclpy.spin(node)
    except config_errors as exc:
        if node is not None:
            raise
        print(f'{prog}: {exc}', file=sys.stderr)
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # SIGINT/SIGTERM shut the context down between bytecodes, possibly in the
        # middle of a callback; what that callback raises then (publishing on a
        # context that is gone) is part of shutting down, not a fault
        if node is None or node.context.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)
