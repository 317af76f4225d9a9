import numpy as np

from world import packets


def test_fifo_serves_oldest_first_and_expires_at_deadline():
    depth = 4
    slots = np.zeros(depth, np.int64)
    queued = 0
    for t, n in enumerate([2, 1, 3]):  # born at steps 0, 1, 2
        queued += packets.arrive(slots, queued, t, n, 100)
        if t < 2:
            assert packets.expire(slots, t) == 0
    served, ages = packets.serve(slots, 2, 3)
    assert served == 3 and ages == 2 * 2 + 1 * 1  # two aged 2, one aged 1
    assert slots.sum() == 3
    assert packets.expire(slots, 2) == 0
    # the step-2 packets expire at the end of step 2 + depth - 1
    for t in range(3, 2 + depth - 1):
        assert packets.expire(slots, t) == 0
    assert packets.expire(slots, 2 + depth - 1) == 3


def test_queue_bound():
    slots = np.zeros(5, np.int64)
    assert packets.arrive(slots, 8, 0, 5, 10) == 2
