"""The programs beside the controller (`ros2 run motion_ctrl NAME`), one command each: record
(and `record --repair`), report, benchmark, demo, scenarios, tune, notch, calibrate, identify,
autotune, draw, soak. What they share is in motion_ctrl.procedures (over ROS), bags, analysis
and plotting; no tool imports another."""
