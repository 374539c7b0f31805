"""The ``thinkfast-run`` process: EGM server, cycle timing, zenoh edge, flight recorder,
real-time thread set-up and the command line around the control core."""
