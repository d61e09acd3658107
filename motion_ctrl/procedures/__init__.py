"""What the PC tools do on a live axis, beside the command lines in `motion_ctrl.tools` that
run them: the session the tools share (start or find the nodes, lockstep or real time, move
and wait, excite and gather: `session`), and the procedures the tools are made of. A tool
(a module of `motion_ctrl.tools`, one command each) imports from here, never from another
tool."""
