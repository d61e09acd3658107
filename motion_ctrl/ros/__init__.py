"""The ROS shell: the controller and plant nodes, parameters from the register table, the
environment every ROS process runs with, the client the tools use, lockstep runs and process
helpers. Nodes only translate parameters, topics, services and timers into calls on the core."""
