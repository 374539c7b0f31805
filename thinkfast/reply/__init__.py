"""The reply process (``thinkfast-run --reply-process``): the controller's replies in a process
of their own, following the plan the planner process (:mod:`thinkfast.daemon.planner_process`)
publishes through shared memory (shared_plan: the plan's seqlock and the row ring; rows: their
layout), and holding the arm on its own status once its planner is lost (orphan_status)."""
