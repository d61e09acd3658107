"""Measurement mathematics, no ROS: ISO 230-2 positioning statistics (iso230) and frequency
response, two-mass fit and loop margins (identify). The tools in motion_ctrl.tools run the
tests over ROS and hand the records to these."""
