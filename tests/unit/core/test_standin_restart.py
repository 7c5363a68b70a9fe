"""Reference time that begins afresh (the reference's clock restarted) in the role's
core (federation.core.standin.Keeper.time_restarted): the instants heard before are
forgotten and epochs kept, so a stand-in acknowledges the restarted leader's new stamps
after a quiet period of its own and claims only after hearing it ask again."""

from __future__ import annotations

from federation.core.standin import Claim, Keeper, Terms

TERMS = Terms(lease=1.0, after=1.5, skew=0.05)


def asking(at: float, epoch: int = 1) -> Claim:
    return Claim("l", "leader", epoch, at, False, asking=True, top=epoch)


def test_a_stand_in_forgets_old_stamps_and_keeps_quiet_again() -> None:
    k = Keeper("s", "stand-in", "l", TERMS)
    for i in range(30):  # 3 s of the leader asking, on the old time base
        k.hear(asking(20.0 + i * 0.1))
        claim = k.tick(20.0 + i * 0.1, 0.0)
    assert claim.ack is not None and claim.ack.at > 22.0
    k.hear(Claim("l", "leader", 1, 0.0, False, top=3))  # an epoch seen since is kept
    k.time_restarted()
    assert k.top == 3 and k.heard is None and k.born is None
    # Reference time now reads 3 s: old stamps are neither acknowledged nor counted.
    claim = k.tick(3.0, 0.0, running=True, ready=True)
    assert claim.ack is None and not claim.holding
    assert "never heard" in claim.why
    k.hear(asking(3.05, epoch=4))
    quiet = [k.tick(3.1 + i * 0.1, 0.0, running=True, ready=True) for i in range(11)]
    assert all(c.ack is None for c in quiet)  # within lease + 4 skew of its new start
    for i in range(5):
        k.hear(asking(4.3 + i * 0.1, epoch=4))
        claim = k.tick(4.3 + i * 0.1, 0.0, running=True, ready=True)
    assert claim.ack is not None and claim.ack.epoch == 4 and claim.ack.at >= 4.3
    assert not claim.holding


def test_a_release_set_on_the_old_time_base_releases_at_once() -> None:
    k = Keeper("s", "stand-in", "l", TERMS)
    k.hear(asking(10.0))
    k.tick(10.0, 0.0, running=True, ready=True)
    claim = k.tick(11.6, 0.0, running=True, ready=True)
    assert claim.holding and claim.epoch == 2
    assert k.hand_back("l", 11.7) is None and k.release_at is not None
    k.time_restarted()
    claim = k.tick(2.0, 0.0, running=True, ready=True)
    assert not claim.holding and claim.until is None
