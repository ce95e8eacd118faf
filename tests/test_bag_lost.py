"""Counting lost messages from publication sequence numbers (flagbot_sim.bag.lost) — no DDS."""
import random

from flagbot_sim.bag.lost import LOST_METADATA_NAME, GapCounter, LostCounter, counts_from_record


def test_one_writer_counts_every_skipped_number_and_starts_at_the_first_taken():
    c = GapCounter()
    seqs = [5, 6, 7, 10, 11, 15, 16]          # joined at 5 (1-4 were before the match: not lost), lost 8, 9, 12-14
    assert [c.add(s) for s in seqs] == [0, 0, 0, 2, 0, 3, 0]
    assert c.lost == 5 and c.taken == 7 and c.unnumbered == 0


def test_interleaved_writers_are_counted_exactly_while_their_numbers_do_not_cross():
    """Two publishers on one topic: the numbers are per writer and the message info does not say which writer sent
    a sample. One writer far ahead of the other (a late joiner, a restart): the loss is counted exactly."""
    rng = random.Random(7)
    a = list(range(1000, 1400))               # writer A, long running
    b = list(range(1, 300))                   # writer B, started later
    lost_a = set(rng.sample(a[1:-1], 40))       # the first and last taken: a loss after the last is unseen
    lost_b = set(rng.sample(b[1:-1], 25))
    stream, ia, ib = [], 0, 0
    while ia < len(a) or ib < len(b):         # interleaved in a random order
        if ib >= len(b) or (ia < len(a) and rng.random() < 0.6):
            stream.append(a[ia]) if a[ia] not in lost_a else None
            ia += 1
        else:
            stream.append(b[ib]) if b[ib] not in lost_b else None
            ib += 1
    c = GapCounter()
    for s in stream:
        c.add(s)
    assert c.lost == len(lost_a) + len(lost_b) == 65


def test_samples_without_a_number_are_counted_as_unnumbered_not_lost():
    c = GapCounter()
    for s in (None, 0, 3, "x", 4, True):
        c.add(s)
    assert c.lost == 0 and c.unnumbered == 4 and c.taken == 6


def test_a_writer_that_went_away_is_forgotten_after_max_streams():
    c = GapCounter(max_streams=2)
    c.add(100)                                 # a writer that is gone
    c.add(1)
    c.add(1)                                   # two new writers: the oldest stream (100) is dropped
    for s in range(2, 200):                    # both new writers run past 100 without a false gap
        c.add(s)
        c.add(s)
    assert c.lost == 0


def test_per_topic_counts_and_their_metadata_record_round_trip():
    lc = LostCounter()
    for s in (1, 2, 5):
        lc.add("/a", s)
    for s in (1, 2, 3):
        lc.add("/b", s)
    assert lc.counts() == {"/a": 2, "/b": 0} and lc.total == 2
    rec = lc.to_record()
    assert counts_from_record(rec) == {"/a": 2, "/b": 0} and rec["total"] == "2"
    assert counts_from_record(None) is None and counts_from_record({"counts": "nonsense"}) is None
    assert LOST_METADATA_NAME == "flagbot_sim.lost_messages"
    assert [lc.first_loss("/b", s) for s in (4, 6, 8, 9)] == [False, True, False, False]   # said once per topic
