"""The servo controller itself, plain Python + numpy + ruckig, no ROS: the register table, the
servo laws (PID / I-PD, feedforward, notch, deadband), backlash and leadscrew compensation, dual
loop, profile and trajectories, settling, the axis and the servo loop that ticks all axes, the
excitation and gather. The ROS nodes (motion_ctrl.ros) and the simulation (motion_ctrl.sim)
drive the same objects."""
