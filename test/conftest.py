"""Shared pytest set-up: a private ROS domain and in-process ROS fixtures."""

import os

# Before anything can initialise rclpy: keep DDS discovery on this host, and
# use a domain of our own so concurrent runs (and any ROS graph already on this
# machine) stay apart. Domain ids above 232 break Fast DDS, so stay in 100-199.
from sorter_ros.env import apply_ros_env_defaults  # noqa: E402 (imports no ROS)

apply_ros_env_defaults()
os.environ['ROS_DOMAIN_ID'] = os.environ.get('SORTER_TEST_DOMAIN_ID') or str(
    100 + os.getpid() % 100
)

import pytest  # noqa: E402


@pytest.fixture
def ros_context():
    """Return a fresh, initialised rclpy Context, shut down after the test."""
    from ros_harness import ros_context_scope

    with ros_context_scope() as ctx:
        yield ctx


@pytest.fixture
def ros(ros_context):
    """Return a RosHarness (nodes + SingleThreadedExecutor) bound to ``ros_context``."""
    from ros_harness import ros_harness_scope

    with ros_harness_scope(ros_context) as harness:
        yield harness


def pytest_configure(config):
    """Drop the core's stale numba kernels before a test calls one (tests call them directly)."""
    from sorter_sim.model.core.cache import check_kernel_cache

    check_kernel_cache()
