"""The owner of a drive group: one client at a time holds a claim; only its commands move the arm.

A client claims the drive and gets a token (random, 128 bit) that it carries in every command
(setpoint, effort command, fault reset, enable). The claim is a lease: it lasts ``lease`` s after
the owner's latest renewal or accepted command, then expires by itself (the owner's process died
or hung). The owner releases it explicitly; then another client may claim.

With no claim held, the drive belongs to the *default owner* (a node name, e.g. the suite's own
executor), whose commands carry no token: the adapter tells :meth:`Ownership.authorize` whether a
token-less command can only have come from that node (it is the sole publisher of the topic).
Nothing here authenticates anyone: the token travels in the clear on the ROS graph. It stops a
stray or mistaken client, not a hostile one.

Every refusal is counted per command kind and kept as the latest reason (for diagnostics). E-stop
is not a command kind here: it is accepted from everyone, always.
"""
from __future__ import annotations

import secrets
import threading
import time
from dataclasses import dataclass
from typing import Callable, Optional

#: the commands that need the drive: setpoints (stamped currents), effort commands (JointState),
#: fault reset (leave the latched safe state) and enable (lifecycle activate)
COMMAND_KINDS = ("setpoint", "command", "fault_reset", "enable")


def qualified_name(name: str, namespace: str = "/") -> str:
    """Fully qualified node name: ``name`` as it is when it starts with '/', else under ``namespace``."""
    name = name.strip()
    if not name or name.startswith("/"):
        return name
    return namespace.rstrip("/") + "/" + name


class ClaimRefused(ValueError):
    """A claim, renewal or release the ownership refuses; the message says why and what to do."""


@dataclass(frozen=True)
class Claim:
    """A claim held: the client's node name (for messages and logs), its token, the lease (s)."""

    client: str
    token: str
    lease: float
    request_id: str = ""      # the client's id of the CLAIM request that made it ("" = none)


@dataclass(frozen=True)
class Decision:
    """Whether a command is accepted, and if not why (one line)."""

    accepted: bool
    reason: str = ""


class Ownership:
    """Claims on one drive group (thread safe); ``clock`` is monotonic seconds.

    Args:
        lease: s, default lease of a claim (renewed by the owner's renewals and accepted commands).
        max_lease: s, the longest lease a client may ask for.
        default_owner: fully qualified node name that commands without a token while no claim is
            held ("" = none: every command needs a claim).
    """

    def __init__(self, lease: float = 2.0, max_lease: float = 3600.0, default_owner: str = "",
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not lease > 0.0 or not max_lease >= lease:
            raise ValueError(f"lease must be > 0 and max_lease >= lease (got {lease}, {max_lease})")
        self.default_lease = float(lease)
        self.max_lease = float(max_lease)
        self.default_owner = default_owner
        self._clock = clock
        self._lock = threading.Lock()
        self._claim: Optional[Claim] = None
        self._expires = 0.0
        self.refused = {k: 0 for k in COMMAND_KINDS}
        self.claims_refused = 0
        self.expired = 0
        self.last_refusal = ""

    # --- claims -----------------------------------------------------------------------------------
    def _live(self) -> Optional[Claim]:
        if self._claim is not None and self._clock() >= self._expires:
            return None
        return self._claim

    def claim(self, client: str, lease: float = 0.0, request_id: str = "") -> Claim:
        """Claim the drive for node ``client`` for ``lease`` s (0 = the default); ClaimRefused
        while another live claim is held (also one of the same name: the token proves the holder).

        ``request_id``: the client's id of this request. The same request repeated (same client,
        same non-empty id, e.g. because its answer was lost) gets the claim it made back, its lease
        renewed, instead of a refusal."""
        client = client.strip()
        if not client:
            raise self._refuse_claim("a claim needs the client's node name")
        lease = self.default_lease if lease <= 0.0 else float(lease)
        if lease > self.max_lease:
            raise self._refuse_claim(f"lease {lease:g} s is longer than the longest allowed, {self.max_lease:g} s")
        with self._lock:
            held = self._live()
            if held is not None and request_id and held.request_id == request_id and held.client == client:
                self._expires = self._clock() + held.lease
                return held
            if held is not None:
                left = self._expires - self._clock()
                raise self._refuse_claim(f"the drive is claimed by {held.client} (lease {held.lease:g} s, "
                                         f"{left:.1f} s left unless renewed); it must release it first")
            self._claim = Claim(client, secrets.token_hex(16), lease, request_id)
            self._expires = self._clock() + lease
            return self._claim

    def _refuse_claim(self, text: str) -> ClaimRefused:
        self.claims_refused += 1
        self.last_refusal = f"claim: {text}"
        return ClaimRefused(text)

    def _holder(self, token: str, what: str) -> Claim:
        held = self._live()
        if held is None:
            raise self._refuse_claim(f"{what}: no claim is held (it was released or expired)")
        if not token or not secrets.compare_digest(token, held.token):
            raise self._refuse_claim(f"{what}: the token is not the one of the claim held by {held.client}")
        return held

    def renew(self, token: str) -> Claim:
        """Extend the owner's lease by its full length from now; ClaimRefused for a wrong token."""
        with self._lock:
            held = self._holder(token, "renew")
            self._expires = self._clock() + held.lease
            return held

    def release(self, token: str) -> Claim:
        """End the owner's claim now; ClaimRefused for a wrong token."""
        with self._lock:
            held = self._holder(token, "release")
            self._claim = None
            return held

    def expire(self) -> Optional[Claim]:
        """Drop a claim whose lease has run out; returns it (once), else None."""
        with self._lock:
            if self._claim is not None and self._clock() >= self._expires:
                gone, self._claim = self._claim, None
                self.expired += 1
                return gone
            return None

    # --- commands ---------------------------------------------------------------------------------
    def authorize(self, kind: str, token: str = "", sender: str = "") -> Decision:
        """May this command move the drive? ``token``: the one the command carries ("" = none);
        ``sender``: the node it came from when the adapter knows it for certain ("" = unknown).
        An accepted command with the owner's token renews its lease; a refusal is counted."""
        if kind not in COMMAND_KINDS:
            raise ValueError(f"unknown command kind {kind!r}; one of {COMMAND_KINDS}")
        with self._lock:
            held = self._live()
            if held is not None:
                if token and secrets.compare_digest(token, held.token):
                    self._expires = self._clock() + held.lease
                    return Decision(True)
                who = f" from {sender}" if sender else ""
                why = "a wrong token" if token else "no token"
                return self._refuse(kind, f"{kind}{who} refused: the drive is claimed by {held.client} "
                                          f"({why})")
            if token:
                return self._refuse(kind, f"{kind} refused: its token belongs to no claim held "
                                          "(released or expired); claim the drive again")
            if self.default_owner and sender == self.default_owner:
                return Decision(True)
            who = f" from {sender}" if sender else ""
            owner = (f"only the default owner {self.default_owner} commands without a claim; "
                     if self.default_owner else "")
            return self._refuse(kind, f"{kind}{who} refused: {owner}claim the drive first (~/claim)")

    def _refuse(self, kind: str, text: str) -> Decision:
        self.refused[kind] += 1
        self.last_refusal = text
        return Decision(False, text)

    # --- status -----------------------------------------------------------------------------------
    @property
    def owner(self) -> str:
        """The node holding a live claim, else the default owner (or "")."""
        with self._lock:
            held = self._live()
        return held.client if held is not None else self.default_owner

    @property
    def claimed(self) -> bool:
        """True while an explicit claim is held (not only the default owner)."""
        with self._lock:
            return self._live() is not None

    def lease_left(self) -> float:
        """s until the live claim expires unless renewed (0 when none)."""
        with self._lock:
            return max(0.0, self._expires - self._clock()) if self._live() is not None else 0.0

    def status(self) -> dict[str, object]:
        """Diagnostics keys: owner, whether claimed, lease left (s), refusal counts, latest refusal."""
        with self._lock:
            held = self._live()
            left = max(0.0, self._expires - self._clock()) if held is not None else 0.0
        out: dict[str, object] = {
            "owner": held.client if held is not None else self.default_owner,
            "owner.claimed": held is not None,
            "owner.lease_left_s": round(left, 3),
            "owner.claims_refused": self.claims_refused,
            "owner.claims_expired": self.expired,
            "owner.refused": sum(self.refused.values()),
        }
        out.update({f"owner.refused.{k}": v for k, v in self.refused.items()})
        out["owner.last_refusal"] = self.last_refusal
        return out
