"""`python -m motion_ctrl.ros.servo_bus relay NAME NAMESPACE LOCAL_DOMAIN`: the relay process
(servo_bus.relay), started by a node's bridge when your domain reaches other hosts."""
import sys

from motion_ctrl.ros.servo_bus import relay

if __name__ == '__main__':
    if sys.argv[1:2] != ['relay'] or len(sys.argv) != 5:
        sys.exit(__doc__)
    sys.exit(relay.main(sys.argv[1:]))
