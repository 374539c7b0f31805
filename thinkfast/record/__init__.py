"""The flight record: its HDF5 format (format), the daemon's non-blocking recorder (recorder,
rows, wire, pipe) and writer process (writer, file), and the tools that read it back (tables,
plot, MCAP export); docs/RECORD_FORMAT.md."""
