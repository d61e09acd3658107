"""The programs beside the controller (`ros2 run motion_ctrl NAME`): record, report and bag
repair, benchmark, demo, scenarios, tune, calibrate, draw, soak."""
