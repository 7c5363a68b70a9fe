"""The scale bench's sync exchanges per second: each link counted once."""

from __future__ import annotations

from federation.bench.scale import _exchanges


def peers(**samples: tuple[int, int]) -> dict[str, object]:
    return {
        "peers": {
            k.replace("_", "/"): {"samples": n, "sharing": s} for k, (n, s) in samples.items()
        }
    }


def test_a_link_two_agents_share_counts_once_though_one_left_it_first() -> None:
    # lab1's a1 and a5 share one link to the leader (130 exchanges); a1 ended first, so
    # a5's last status reports the link as its own (sharing 1). Dividing by sharing had
    # counted 65 + 130.
    last = [
        (0, peers(lab1_a1=(13, 1), lab1_a5=(13, 1))),  # the leader: one link per peer
        (1, peers(lab0_a0=(130, 2))),
        (1, peers(lab0_a0=(130, 1))),
    ]
    assert _exchanges(last) == 13 + 13 + 130


def test_links_of_different_workers_to_one_peer_are_each_counted() -> None:
    last = [(1, peers(lab0_a0=(130, 1))), (2, peers(lab0_a0=(128, 1))), (3, {"peers": {}})]
    assert _exchanges(last) == 258
