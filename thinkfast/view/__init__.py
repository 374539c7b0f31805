"""The views: the daemon's live view and a flight record drawn again, in Rerun or Foxglove.

One 3-D scene (scene: geometry, Foxglove entities) and one set of Foxglove channels (channels;
their ROS 2 topics: ros_topics) for every view. Live: the daemon's queue drawn in idle time
(live), by the Rerun painter (rerun_painter) or on the Foxglove SDK's server (foxglove). A
record: its calls kept in time order (replay), drawn in Rerun (record_rerun), played at its pace
on the Foxglove server (foxglove_replay), or written as MCAP (mcap). docs/LIVE_VIEW.md.
"""
