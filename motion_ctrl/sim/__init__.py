"""The simulated machine, no ROS: the lead-screw "backlash slide" physics (plant) and the
in-process harness that ticks the core's ServoLoop against it."""
