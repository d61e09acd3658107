"""msg_defs streams: a publish the middleware refuses is counted and reported, never raised (a
slow observer must not kill the servo loop: seen as "Failed to publish: cannot publish data"
ending the controller in its tick); the lazily loaded helpers."""
import subprocess
import sys

import msg_defs as md


class RefusingPublisher:
    topic_name = '/reference_states'

    def __init__(self):
        self.calls = 0

    def get_subscription_count(self):
        return 1

    def publish(self, msg):
        self.calls += 1
        raise RuntimeError('Failed to publish: cannot publish data')


def test_a_refused_publish_is_counted_and_reported_not_raised():
    errors = []
    stream = md.JointStateStream(RefusingPublisher(), lambda topic, e: errors.append((topic, e)))
    stream.publish(None, ['x'], [0.1], [0.0])
    stream.publish(None, ['x'], [0.2], [0.0])
    assert stream.failures == 2 and stream.publisher.calls == 2
    assert [t for t, _ in errors] == ['/reference_states'] * 2
    assert 'cannot publish data' in str(errors[0][1])
    assert list(stream.msg.position) == [0.2]          # the latest sample is still held


def test_a_plain_stream_sends_and_says_whether_it_did():
    class Publisher(RefusingPublisher):
        def publish(self, msg):
            self.calls += 1
    ok = md.Stream(Publisher())
    assert ok.send(object()) and ok.failures == 0
    refused = md.Stream(RefusingPublisher())       # no on_error: counted only
    assert not refused.send(object()) and refused.failures == 1


def test_the_helpers_are_functions_whichever_is_used_first():
    """`md.Stream` first imports the module `msg_defs.joint_state`, whose import binds the
    package's `joint_state` to the module: the function must still be what `md.joint_state`
    gives (a fresh interpreter, so that the order is this one)."""
    code = ('import msg_defs as md; md.Stream; '
            'print(callable(md.joint_state) and md.joint_state.__name__)')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == 'joint_state'
