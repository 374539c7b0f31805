"""Fault campaign against the real ``thinkfast-run`` daemon: a hostile or faulty ABB cell.

* :mod:`.egm_pb`: ABB's ``egm.proto`` message classes, built independently of the daemon's;
* :mod:`.controller`: the fault-injecting controller (servo model on its own 250 Hz clock);
* :mod:`.senders`, :mod:`.flood`: malformed datagrams, a second sender, a bounded flood;
* :mod:`.fuzz`: hostile detection payloads over zenoh (a process of its own);
* :mod:`.checker`: independent checks of the applied commands, per controller cycle;
* :mod:`.monitor`, :mod:`.cell`: the daemon's status and setpoints; the cell around the daemon;
* :mod:`.probe`: host stall probe (attributes missed replies to the machine);
* :mod:`.scenarios` and friends: the scenarios run by ``bench/faults.py``.
"""
