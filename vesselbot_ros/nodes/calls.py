"""Service calls that survive a dropped first answer.

Fast DDS (rmw_fastrtps 8.x, ``rmw_response.cpp``) drops a service's answer
when the server has not yet matched the calling client's response reader
100 ms after the request came in; the server logs ``failed to send response
(timeout): client will not receive response`` and the client waits forever.
``wait_for_service`` does not rule it out: it reports the server's endpoints
as the client sees them, not the client's as the server sees them.  On a
loaded machine it happens to a fresh client's first call (measured: 1 of 60
fresh clients under six busy loops on two cores).  Once one answer came
through, the path stays matched.

:class:`Resend` sends a request again, with a growing interval, until one
answer arrives.  Use it for requests whose repetition changes nothing (a
query, a state the server is already in, a refused request), and make a
fresh client's first call such a request (:func:`prime`) before one that must
run exactly once.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

__all__ = ["Resend", "prime", "FIRST_RESEND_S", "MAX_RESEND_S"]

#: The first resend after this long without an answer (wall s); the interval doubles up to :data:`MAX_RESEND_S`.
FIRST_RESEND_S = 0.5
MAX_RESEND_S = 4.0


class Resend:
    """One logical call, sent again until answered (see module doc).

    ``send`` makes one request and returns its future (``client.call_async``,
    ``action_client.send_goal_async``); ``forget`` (optional) tells the client
    to stop waiting for a superseded future.  Poll :meth:`done` from the
    thread that spins the client's node, or from any thread while another
    spins it; it resends when due.
    """

    def __init__(self, send: Callable[[], Any], forget: Callable[[Any], None] | None = None,
                 first_resend_s: float = FIRST_RESEND_S, max_resend_s: float = MAX_RESEND_S) -> None:
        self._send_fn, self._forget = send, forget
        self._interval, self._max = float(first_resend_s), float(max_resend_s)
        self._futures: list[Any] = []
        self._answer: Any = None
        self._send()

    @classmethod
    def service(cls, client: Any, request: Any, **kw: float) -> Resend:
        """A service call on an rclpy ``Client``."""
        return cls(lambda: client.call_async(request), client.remove_pending_request, **kw)

    @property
    def sends(self) -> int:
        """How many times the request went out."""
        return len(self._futures)

    def _send(self) -> None:
        self._futures.append(self._send_fn())
        self._due = time.monotonic() + self._interval
        self._interval = min(2.0 * self._interval, self._max)

    def done(self) -> bool:
        """True once an answer came; else resend if due and return False."""
        if self._answer is not None:
            return True
        for fut in self._futures:
            if fut.done():
                self._answer = fut
                if self._forget is not None:
                    for other in self._futures:
                        if other is not fut and not other.done():
                            self._forget(other)
                return True
        if time.monotonic() >= self._due:
            self._send()
        return False

    def result(self) -> Any:
        """The first answer's result (``None`` before :meth:`done` is True)."""
        return None if self._answer is None else self._answer.result()

    def wait(self, timeout_s: float, spin: Callable[[float], None] | None = None) -> bool:
        """Wait for the answer: ``spin(step_s)`` if this thread spins the node, else sleep; True if answered."""
        deadline = time.monotonic() + timeout_s
        while not self.done():
            if time.monotonic() >= deadline:
                return False
            if spin is None:
                time.sleep(0.01)
            else:
                spin(0.02)
        return True


def prime(client: Any, request: Any, timeout_s: float, spin: Callable[[float], None] | None = None) -> Any:
    """Send a harmless ``request`` until answered, so that the client's next call's answer cannot be dropped.

    Returns the answer, or ``None`` after ``timeout_s``.
    """
    call = Resend.service(client, request)
    return call.result() if call.wait(timeout_s, spin) else None
