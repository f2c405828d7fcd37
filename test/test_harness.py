"""The in-process ROS test harness works against real DDS."""

import os

import pytest
from ros_harness import ros_context_scope, ros_harness_scope
from std_msgs.msg import Bool
from std_srvs.srv import SetBool

pytestmark = pytest.mark.ros


def test_publisher_subscriber_round_trip(ros):
    assert ros.context.ok()
    pub_node = ros.make_node('harness_pub')
    sub_node = ros.make_node('harness_sub')
    received = []
    sub_node.create_subscription(Bool, 'harness_flag', received.append, 10)
    pub = pub_node.create_publisher(Bool, 'harness_flag', 10)

    ros.spin_until(lambda: pub.get_subscription_count() > 0, message='subscriber matched')

    def publish_and_check():
        pub.publish(Bool(data=True))
        return bool(received)

    # Publish repeatedly: the first sample may go out before the reader is ready.
    ros.spin_until(publish_and_check, message='Bool on /harness_flag')
    assert received[0].data is True


def test_service_round_trip(ros):
    server = ros.make_node('harness_server')
    client_node = ros.make_node('harness_client')
    calls = []

    def handle(request, response):
        calls.append(request.data)
        response.success = True
        response.message = f'set to {request.data}'
        return response

    server.create_service(SetBool, 'harness_set', handle)
    client = client_node.create_client(SetBool, 'harness_set')

    response = ros.call(client, SetBool.Request(data=True))

    assert calls == [True]
    assert response.success
    assert response.message == 'set to True'


def test_call_fails_with_message_when_service_absent(ros):
    client = ros.make_node('harness_lonely').create_client(SetBool, 'harness_nobody')
    with pytest.raises(pytest.fail.Exception, match='harness_nobody'):
        ros.call(client, SetBool.Request(data=True), timeout_sec=0.3)


def test_spin_until_fails_with_message_on_timeout(ros):
    ros.make_node('harness_idle')
    with pytest.raises(pytest.fail.Exception) as excinfo:
        ros.spin_until(lambda: False, timeout_sec=0.2, message='a thing that never happens')
    assert str(excinfo.value) == 'timed out after 0.2s waiting for: a thing that never happens'


def test_spin_for_runs_timers(ros):
    node = ros.make_node('harness_timer')
    ticks = []
    node.create_timer(0.02, lambda: ticks.append(1))
    ros.spin_for(0.3)
    assert len(ticks) >= 3


def test_add_rejects_node_from_another_context(ros):
    with ros_context_scope() as other:
        import rclpy

        stranger = rclpy.create_node('harness_stranger', context=other)
        try:
            with pytest.raises(ValueError, match='another rclpy context'):
                ros.add(stranger)
        finally:
            stranger.destroy_node()


def test_scopes_shut_down_context_and_destroy_nodes():
    with ros_context_scope() as ctx:
        assert ctx.ok()
        with ros_harness_scope(ctx) as harness:
            node = harness.make_node('harness_scoped')
            assert harness.add(node) is node  # adding twice is harmless
            assert len(harness.nodes) == 1
        assert harness.nodes == []
        assert ctx.ok()
    assert not ctx.ok()


def test_context_shut_down_even_if_body_raises():
    with pytest.raises(RuntimeError):
        with ros_context_scope() as ctx:
            raise RuntimeError('boom')
    assert not ctx.ok()


def test_tests_use_a_private_domain():
    domain = int(os.environ['ROS_DOMAIN_ID'])
    expected = os.environ.get('SORTER_TEST_DOMAIN_ID')
    if expected:
        # the first worker takes the given domain, each next one the next (conftest)
        worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
        assert domain == int(expected) + (int(worker[2:]) if worker[2:].isdigit() else 0)
    else:
        assert 100 <= domain <= 199
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']
