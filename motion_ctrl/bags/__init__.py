"""The rosbag2 bags (MCAP storage, the `rosbags` library) the tools share: recording the
slide's topics (`writer`: `Recorder`), a bag that survives its recorder being killed (`repair`:
the periodic flush and `record --repair`), reading a bag into one record per axis (`reader`)
and the report of a bag: its moves' figures and plots (`report`)."""
