"""Resend: a call whose answer was dropped goes out again until one answer arrives, and only then stops."""

from __future__ import annotations

import time

from vesselbot_ros.nodes import calls
from vesselbot_ros.nodes.calls import Resend, prime


class _Future:
    def __init__(self) -> None:
        self._result = None

    def done(self) -> bool:
        return self._result is not None

    def result(self):
        return self._result


class _Client:
    """Drops the answers of the first ``lost`` requests (the server never matched the reader); answers the rest."""

    def __init__(self, lost: int) -> None:
        self.lost, self.sent, self.forgotten = lost, [], []

    def call_async(self, request):
        fut = _Future()
        self.sent.append((request, fut))
        if len(self.sent) > self.lost:
            fut._result = ("answer", request, len(self.sent))
        return fut

    def remove_pending_request(self, fut) -> None:
        self.forgotten.append(fut)


def test_an_answered_call_is_sent_once():
    client = _Client(lost=0)
    call = Resend.service(client, "q")
    assert call.done() and call.result() == ("answer", "q", 1) and call.sends == 1
    assert call.done() and call.sends == 1  # polled again: nothing more goes out
    assert client.forgotten == []


def test_a_dropped_answer_is_sent_again_with_a_growing_interval_until_answered(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(calls.time, "monotonic", lambda: now[0])
    client = _Client(lost=3)
    call = Resend.service(client, "q", first_resend_s=0.5, max_resend_s=1.0)
    assert not call.done() and call.sends == 1
    now[0] += 0.49
    assert not call.done() and call.sends == 1  # not due yet
    now[0] += 0.01
    assert not call.done() and call.sends == 2  # due at 0.5 s
    now[0] += 0.99
    assert not call.done() and call.sends == 2  # the interval doubled ...
    now[0] += 0.01
    assert not call.done() and call.sends == 3
    now[0] += 1.0
    assert not call.done() and call.sends == 4  # ... up to its cap
    assert call.done() and call.result() == ("answer", "q", 4)
    # the client stops waiting for the three superseded requests, and nothing more is sent
    assert client.forgotten == [f for _, f in client.sent[:3]]
    now[0] += 100.0
    assert call.done() and call.sends == 4


def test_wait_and_prime_return_the_answer_or_none_after_the_timeout():
    assert prime(_Client(lost=1), "harmless", timeout_s=5.0) == ("answer", "harmless", 2)
    t0 = time.monotonic()
    never = Resend.service(_Client(lost=10**9), "q", first_resend_s=0.01, max_resend_s=0.02)
    spun = []
    assert not never.wait(0.2, spin=spun.append)
    assert 0.2 <= time.monotonic() - t0 < 5.0 and spun and never.sends >= 5
    assert never.result() is None
