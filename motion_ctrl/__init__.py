"""motion_ctrl: PMAC / Galil / Delta RMC style servo axes as ROS 2 nodes, with a physics model of
the Galil manual's lead-screw backlash slide. The servo laws, compensation, profiles, settling
logic and plant are plain Python modules (no rclpy); the nodes are a thin shell around them."""
