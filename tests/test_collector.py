"""The collector is turned on again with the objects made while it was off promoted to the oldest generation,
so the first young collection after a convert does not walk the whole job."""

import gc

from doodlecam.collector import no_collections


class Node:
    def __init__(self):
        self.me = self  # a cycle: garbage only for the cyclic collector


def test_objects_made_without_collections_are_promoted_and_garbage_is_still_collected():
    assert gc.isenabled()
    with no_collections():
        assert not gc.isenabled()
        kept = [Node() for _ in range(5000)]
        Node()  # garbage in a cycle
    assert gc.isenabled() and gc.get_freeze_count() == 0
    young = {id(o) for o in gc.get_objects(generation=0)}
    old = {id(o) for o in gc.get_objects(generation=2)}
    assert not any(id(o) in young for o in kept) and all(id(o) in old for o in kept)
    assert gc.get_count()[0] < 100  # the young generation starts empty
    assert gc.collect() >= 1  # the full collection still finds the cycle
    del kept


def test_a_callers_state_is_kept():
    gc.disable()
    try:
        with no_collections():
            pass
        assert not gc.isenabled()  # it was off: it stays off
    finally:
        gc.enable()
    mine = [Node() for _ in range(100)]
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        with no_collections():
            Node()
        assert gc.isenabled() and gc.get_freeze_count() == frozen  # the caller's frozen objects stay frozen
    finally:
        gc.unfreeze()
    del mine
