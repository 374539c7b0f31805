"""Controller links: the wires between the control core and a robot controller, and the loop's
timing on them.

A link (:class:`thinkfast.control.link.ControllerLink`) receives the controller's feedback, hands
it to the driver as a neutral :class:`~thinkfast.control.link.Feedback` and sends the setpoint
back. EGM (egm, on egm_server; its addresses: egm_address; its reply times: reply_times) is the
real one; the registry names every link the daemon may open. A loop serving a link stands in
the controller's cycle (cycle: when to sleep, spin, prepare, work), collects garbage between
replies (gc_rule) and may own a CPU under SCHED_FIFO (rt_thread).
"""
