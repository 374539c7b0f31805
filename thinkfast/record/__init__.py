"""The flight record: its HDF5 format (format), the daemon's non-blocking recorder (recorder,
wire, pipe) and writer process (writer, file), and the tools that read it back (tables,
plot, MCAP export and its ROS 2 topics: ros_topics); docs/RECORD_FORMAT.md."""
