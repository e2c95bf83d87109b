"""The fault mavlink-loss (sim_world/vehicle/link_loss.py): its window counts simulated seconds from
liftoff, and the vehicle's journal says when the flight link went and came back."""
from __future__ import annotations

import threading

from sim_world.vehicle.journal import Journal
from sim_world.vehicle.link_loss import LinkLoss


def test_the_window_starts_at_liftoff_and_is_said_once_each_way():
    now = {"t": 0.0, "air": False}
    journal = Journal(threading.RLock(), sim_time=lambda: now["t"])
    loss = LinkLoss(10.0, 5.0, clock=lambda: (now["t"], now["air"]), journal=journal)

    def at(t, air=True):
        now.update(t=t, air=air)
        return loss.down()
    assert [at(50.0, air=False), at(100.0), at(109.9)] == [False, False, False]   # liftoff at 100
    assert [at(110.0), at(114.9), at(115.0), at(111.0)] == [True, True, False, False]   # once over, over
    assert [text for _, text in journal.events] == [
        "fault injected: the flight link carries nothing for 5 s, from 10 s after liftoff",
        "fault over: the flight link is back (2 message(s) lost)"]
