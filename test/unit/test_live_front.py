"""live_front: which handshakes the live view's port passes on to the SDK's server, renamed or refused.

The same handshakes against a running live view (raw HTTP over a socket) are in
``test_live.py``; Foxglove's own client offering each name is ``test/integration/test_live.py``.
"""

from __future__ import annotations

import base64
import os

import pytest

from vesselbot_ros.live_front import SDK_SUBPROTOCOL, SPEC_SUBPROTOCOL, offered_subprotocols, rewrite_request, rewrite_response


def _head(*protocol_headers: str) -> bytes:
    key = base64.b64encode(os.urandom(16)).decode("ascii")
    lines = ["GET / HTTP/1.1", "Host: 127.0.0.1", "Upgrade: websocket", "Connection: Upgrade",
             f"Sec-WebSocket-Key: {key}", "Sec-WebSocket-Version: 13"]
    lines += [f"Sec-WebSocket-Protocol: {p}" for p in protocol_headers]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("ascii")


def test_an_offer_of_the_spec_name_alone_is_passed_on_as_the_sdk_name_and_answered_as_offered():
    head = _head("foxglove.websocket.v1")
    hs = rewrite_request(head)
    assert hs.refused is None and hs.answer_as == SPEC_SUBPROTOCOL
    assert offered_subprotocols(hs.head) == [SDK_SUBPROTOCOL] and hs.head.endswith(b"\r\n\r\n")
    # everything else of the head is kept, in order
    assert [ln for ln in hs.head.split(b"\r\n") if b"Protocol" not in ln] == \
        [ln for ln in head.split(b"\r\n") if b"Protocol" not in ln]
    answer = b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\nX: 1\r\n\r\n"
    assert rewrite_response(answer, hs.answer_as) == \
        b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.websocket.v1\r\nX: 1\r\n\r\n"


@pytest.mark.parametrize("offers", [("foxglove.sdk.v1",), ("foxglove.websocket.v1, foxglove.sdk.v1",),
                                    ("foxglove.websocket.v1", "foxglove.sdk.v1")])
def test_an_offer_with_the_sdk_name_is_passed_on_unchanged(offers):
    head = _head(*offers)
    assert rewrite_request(head) == (head, None, None)
    answer = b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n"
    assert rewrite_response(answer, None) == answer


@pytest.mark.parametrize("offers", [(), ("mqtt",), ("foxglove.websocket.v2",)])
def test_an_offer_of_neither_name_is_refused_naming_both(offers):
    hs = rewrite_request(_head(*offers))
    assert hs.refused is not None and hs.refused.startswith(b"HTTP/1.1 400 Bad Request\r\n")
    assert b"foxglove.sdk.v1 or foxglove.websocket.v1" in hs.refused
