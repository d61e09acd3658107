"""Measurement mathematics, no ROS: ISO 230-2 positioning statistics (iso230), frequency
response, two-mass fit and loop margins (identify), the gain proposal (autotune), the rest on a
sticky slide (rest), the contour error (contour) and the figures of a move (moves). The
procedures in motion_ctrl.procedures run the tests over ROS and hand the records to these."""
