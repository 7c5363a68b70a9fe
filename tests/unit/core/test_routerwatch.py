"""federation.core.routerwatch: a session's router going and coming back, from
transport and link events in Zenoh's order (a link closes before its transport and
opens after it)."""

from __future__ import annotations

import logging

from federation.core.routerwatch import Note, RouterWatch

A, B = "aaaa", "bbbb"
AT = "tcp/127.0.0.1:7447"


def up(watch: RouterWatch, zid: str, at: str, now: float) -> list[Note | None]:
    return [watch.transport(zid, True, True, now), watch.link(zid, at, True, now)]


def down(watch: RouterWatch, zid: str, at: str, now: float) -> list[Note | None]:
    return [watch.link(zid, at, False, now), watch.transport(zid, True, False, now)]


def test_the_first_router_is_not_news() -> None:
    assert up(RouterWatch("agent kiruna/knatte"), A, AT, 0.0) == [None, None]


def test_a_lost_router_is_named_with_its_endpoint_and_its_return_with_the_time_without() -> None:
    watch = RouterWatch("agent kiruna/knatte")
    up(watch, A, AT, 0.0)
    assert down(watch, A, AT, 10.0) == [
        None,
        Note(
            logging.WARNING,
            "agent kiruna/knatte: the router at tcp/127.0.0.1:7447 is gone: every other "
            "agent is out of reach (and shows as left) until a router is back",
        ),
    ]
    # A restarted router has a new zid; its link names where it is.
    assert up(watch, B, AT, 17.25) == [
        None,
        Note(
            logging.INFO,
            "agent kiruna/knatte: the router at tcp/127.0.0.1:7447 is back after 7.2 s without one",
        ),
    ]
    assert down(watch, B, AT, 20.0)[1] is not None  # gone again: said again


def test_peers_are_not_routers() -> None:
    watch = RouterWatch("x")
    up(watch, A, AT, 0.0)
    assert watch.transport(B, False, True, 1.0) is None
    assert watch.link(B, "tcp/127.0.0.1:9000", True, 1.0) is None
    assert watch.link(B, "tcp/127.0.0.1:9000", False, 2.0) is None
    assert watch.transport(B, False, False, 2.0) is None


def test_one_of_two_routers_gone_is_said_without_out_of_reach() -> None:
    watch = RouterWatch("x")
    up(watch, A, AT, 0.0)
    up(watch, B, "tcp/127.0.0.1:7448", 0.0)
    note = down(watch, A, AT, 5.0)[1]
    assert note == Note(logging.WARNING, "x: the router at tcp/127.0.0.1:7447 is gone")
    assert up(watch, A, AT, 6.0) == [None, None]  # another router was there all along


def test_a_router_whose_link_was_never_seen_is_named_by_its_zid() -> None:
    watch = RouterWatch("x")
    watch.transport(A, True, True, 0.0)
    note = watch.transport(A, True, False, 1.0)
    assert note is not None and "the router at zid aaaa is gone" in note.text


def test_either_order_of_the_two_listeners_names_the_endpoint() -> None:
    """Each listener runs on a thread of its own, so a link's event may come before its
    transport's (the history at start, a router's return) or after (a close)."""
    watch = RouterWatch("agent kiruna/knatte")
    assert watch.link(A, AT, True, 0.0) is None  # the history's link first
    assert watch.transport(A, True, True, 0.0) is None
    gone = watch.transport(A, True, False, 10.0)  # the transport's close first
    assert gone is not None and f"the router at {AT} is gone" in gone.text
    assert watch.link(A, AT, False, 10.0) is None
    assert watch.link(A, AT, True, 12.5) is None  # back: the link's event first
    back = watch.transport(A, True, True, 12.5)
    assert back is not None
    assert back.text == f"agent kiruna/knatte: the router at {AT} is back after 2.5 s without one"
