"""Session 15 review (R): ``selfcal._own_move`` caches the focal length's own move per joint fit by
``id(fit)``; a fit freed during ``decide``'s loop (a refit replaced it and nothing else kept it) leaves
its id free for a later fit, which would then be given the freed fit's move (a stale focal-choice part
of the sigma). The cache keeps each fit it measured alive, so an id cannot be reused while cached."""

from __future__ import annotations

import weakref

import numpy as np

from xcalib.calib import selfcal


class _Fit:  # what _own_move reads of a joint fit
    def __init__(self):
        self.intr, self.pose, self.principal_shift_px, self.dt_s = None, None, None, 0.0


def test_a_cached_fit_stays_alive_so_a_later_fit_never_gets_its_move(monkeypatch):
    calls = []

    def own(frames, intr, pose, given, occlusion):
        calls.append(1)
        return np.full(6, float(len(calls)))

    monkeypatch.setattr(selfcal, "focal_own_move", own)
    moves: dict = {}
    first = _Fit()
    m1 = selfcal._own_move(moves, first, [], None, None, None)
    alive = weakref.ref(first)
    del first
    assert alive() is not None  # its id stays taken while its move is cached
    later = [_Fit() for _ in range(2000)]  # (without that, one of these may sit at the freed address)
    m2 = [selfcal._own_move(moves, f, [], None, None, None) for f in later[:50]]
    assert len(calls) == 51 and all(not np.array_equal(m1, m) for m in m2)
    assert selfcal._own_move(moves, alive(), [], None, None, None) is m1 and len(calls) == 51
