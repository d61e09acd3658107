"""`hardware: canopen`: CiA 402 servo drives in cyclic synchronous torque mode on one CAN bus
(CiA 301 communication, CiA 402 drive profile, CiA 406 encoders), through the `canopen` and
`python-can` libraries, and an emulated drive that puts the simulated slide behind the same
object dictionary. ROS-free: the controller node and the `virtual_drive` node (motion_ctrl.ros)
only translate parameters into these objects.

* `cia402`: the drive profile's objects, controlword commands, statusword states and the state
  machine (the drive's side and the master's enable / disable sequences);
* `busload`: what a cycle's frames cost on the bus and the highest rate a bitrate carries;
* `objects`: the shipped EDS files and the PDO mapping the master writes;
* `master`: `CanopenHardware`, the servo loop's hardware interface on a CANopen bus (SYNC
  producer, PDO exchange, start-up checks, fault and heartbeat monitoring);
* `virtual_drive`: the emulated CiA 402 drive and CiA 406 encoder around `sim.plant.SlidePlant`.
"""
