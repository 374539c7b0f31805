"""Controller links: the wires between the control core and a robot controller.

A link (:class:`thinkfast.control.link.ControllerLink`) receives the controller's feedback, hands
it to the driver as a neutral :class:`~thinkfast.control.link.Feedback` and sends the setpoint
back. EGM (:mod:`thinkfast.link.egm`, on :mod:`thinkfast.link.egm_server`) is the real one; the
registry (:mod:`thinkfast.link.registry`) names every link the daemon may open.
"""
