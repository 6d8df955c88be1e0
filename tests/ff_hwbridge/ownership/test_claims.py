"""Claims on a drive group: one owner, tokens, leases, refusals counted."""
import pytest

from ff_hwbridge.ownership import ClaimRefused, Ownership, qualified_name


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_only_the_owner_commands_and_others_are_counted():
    clock = Clock()
    own = Ownership(lease=2.0, clock=clock)
    a = own.claim("/client_a")
    assert own.owner == "/client_a" and own.claimed
    with pytest.raises(ClaimRefused, match="claimed by /client_a"):
        own.claim("/client_b")
    with pytest.raises(ClaimRefused):
        own.claim("/client_a")          # the name alone does not prove the holder
    for kind in ("setpoint", "command", "fault_reset", "enable"):
        assert own.authorize(kind, a.token).accepted
        d = own.authorize(kind, "", sender="/client_b")
        assert not d.accepted and "/client_b" in d.reason and "claimed by /client_a" in d.reason
        assert not own.authorize(kind, "f" * 32).accepted
    assert own.refused == {"setpoint": 2, "command": 2, "fault_reset": 2, "enable": 2}
    assert own.status()["owner.refused"] == 8 and own.claims_refused == 2
    with pytest.raises(ClaimRefused):
        own.release("f" * 32)
    own.release(a.token)
    assert not own.claimed and not own.authorize("setpoint", a.token).accepted
    b = own.claim("/client_b")
    assert own.authorize("setpoint", b.token).accepted


def test_a_repeated_claim_request_gets_the_claim_it_made_and_nothing_else_does():
    clock = Clock()
    own = Ownership(lease=2.0, clock=clock)
    a = own.claim("/a", request_id="r1")
    clock.t += 1.5
    again = own.claim("/a", request_id="r1")       # its answer was lost: the same claim, renewed
    assert again.token == a.token
    clock.t += 1.9
    assert own.claimed and own.owner == "/a"
    for client, rid in (("/a", "r2"), ("/b", "r1"), ("/a", "")):
        with pytest.raises(ClaimRefused, match="claimed by /a"):
            own.claim(client, request_id=rid)
    own.release(a.token)
    with pytest.raises(ClaimRefused):
        own.renew(a.token)
    b = own.claim("/a", request_id="r1")           # after release the id makes a new claim
    assert b.token != a.token


def test_the_lease_is_renewed_by_traffic_and_expires_without_it():
    clock = Clock()
    own = Ownership(lease=2.0, clock=clock)
    a = own.claim("/a")
    clock.t += 1.5
    assert own.authorize("setpoint", a.token).accepted      # renews: 2 s from now
    clock.t += 1.9
    assert own.claimed and own.expire() is None
    own.renew(a.token)
    clock.t += 1.99
    assert own.claimed
    clock.t += 0.02
    assert not own.claimed
    gone = own.expire()
    assert gone is not None and gone.client == "/a" and own.expire() is None and own.expired == 1
    with pytest.raises(ClaimRefused, match="released or expired"):
        own.renew(a.token)
    assert own.claim("/b", lease=5.0).lease == 5.0
    with pytest.raises(ClaimRefused, match="longest"):
        Ownership(lease=1.0, max_lease=10.0).claim("/c", lease=11.0)


def test_the_default_owner_commands_only_while_nobody_claims():
    clock = Clock()
    own = Ownership(lease=1.0, default_owner="/ff_executor", clock=clock)
    assert own.owner == "/ff_executor" and not own.claimed
    assert own.authorize("setpoint", sender="/ff_executor").accepted
    assert not own.authorize("setpoint", sender="").accepted       # sender not certain
    assert not own.authorize("setpoint", sender="/other").accepted
    c = own.claim("/operator")
    assert not own.authorize("setpoint", sender="/ff_executor").accepted
    own.release(c.token)
    assert own.authorize("setpoint", sender="/ff_executor").accepted


def test_names_and_bad_arguments():
    assert qualified_name("ff_executor", "/arm_a") == "/arm_a/ff_executor"
    assert qualified_name("ff_executor", "/") == "/ff_executor"
    assert qualified_name("/x/y", "/arm_a") == "/x/y" and qualified_name("") == ""
    with pytest.raises(ValueError):
        Ownership(lease=0.0)
    with pytest.raises(ValueError):
        Ownership().authorize("estop")
    with pytest.raises(ClaimRefused, match="node name"):
        Ownership().claim(" ")
