"""Claim a bridge's drive group from an rclpy node, keep the claim alive, release it.

The bridge (``ff_hwbridge``) moves the arm only on its owner's commands: a client claims the drive
through ``<bridge>/claim`` (ff_msgs/srv/ClaimDrive), gets a token and carries it in every command
(``CurrentSetpoint.token``, the effort command's ``header.frame_id``, ``OwnerCommand.token``). The
claim is a lease renewed by every accepted command; :class:`DriveClaim` also renews it from a
timer (every third of the lease), so an owner that is idle but alive keeps the drive, and one
whose process died loses it a lease later.
"""
from __future__ import annotations

import secrets
import threading
import time
from typing import Any, Optional

from ff_msgs.srv import ClaimDrive, OwnerCommand


class ClaimError(RuntimeError):
    """The bridge refused a claim request or did not answer; the message says why."""


def _wait(future: Any, timeout: float, what: str) -> Any:
    end = time.monotonic() + timeout
    while not future.done() and time.monotonic() < end:
        time.sleep(0.005)
    if not future.done():
        raise ClaimError(f"{what}: no answer within {timeout:g} s")
    return future.result()


#: s, how long one CLAIM request waits for its answer before it is sent again
CLAIM_RESEND = 2.0


def _claim_until_answered(cli: Any, client: str, lease: float, timeout: float, what: str) -> Any:
    """Send CLAIM with a fresh request id, again every CLAIM_RESEND s until one answer arrives
    (within ``timeout`` s). A service answer can be lost while the bridge has not yet matched a new
    client's response reader (``wait_for_service`` sees only the request side); the bridge answers
    a repeated request id with the claim it already made, so a resend never locks the drive."""
    req = ClaimDrive.Request(action=ClaimDrive.Request.CLAIM, client=client, lease=float(lease),
                             token=secrets.token_hex(16))
    end = time.monotonic() + timeout
    futures = [cli.call_async(req)]
    next_send = time.monotonic() + CLAIM_RESEND
    while time.monotonic() < end:
        for fut in futures:
            if fut.done():
                return fut.result()
        if time.monotonic() >= next_send:
            futures.append(cli.call_async(req))
            next_send = time.monotonic() + CLAIM_RESEND
        time.sleep(0.005)
    raise ClaimError(f"{what}: no answer within {timeout:g} s ({len(futures)} requests sent)")


def call_claim(node: Any, bridge: str, action: int, *, client: str = "", token: str = "",
               lease: float = 0.0, timeout: float = 10.0) -> Any:
    """One ``<bridge>/claim`` call (the node must be spun by an executor on another thread);
    returns the response, ClaimError when the service is missing or silent. CLAIM is resent
    until answered (``token`` is ignored for it)."""
    cli = node.create_client(ClaimDrive, f"{bridge.rstrip('/')}/claim")
    try:
        if not cli.wait_for_service(timeout_sec=timeout):
            raise ClaimError(f"service {bridge}/claim is not available (is the bridge configured?)")
        if action == ClaimDrive.Request.CLAIM:
            return _claim_until_answered(cli, client, lease, timeout, f"{bridge}/claim")
        req = ClaimDrive.Request(action=action, client=client, token=token, lease=float(lease))
        return _wait(cli.call_async(req), timeout, f"{bridge}/claim")
    finally:
        node.destroy_client(cli)


def owner_command(node: Any, bridge: str, command: int, token: str, timeout: float = 10.0) -> Any:
    """``<bridge>/owner_command`` (FAULT_RESET or ENABLE) with the claim's token; the response."""
    cli = node.create_client(OwnerCommand, f"{bridge.rstrip('/')}/owner_command")
    try:
        if not cli.wait_for_service(timeout_sec=timeout):
            raise ClaimError(f"service {bridge}/owner_command is not available")
        return _wait(cli.call_async(OwnerCommand.Request(command=command, token=token)), timeout,
                     f"{bridge}/owner_command")
    finally:
        node.destroy_client(cli)


class DriveClaim:
    """The drive of ``bridge`` claimed for ``node`` (spun on another thread) until :meth:`release`.

    ``lease`` s (0 = the bridge's ``claim_lease``); renewed every third of it from a timer of the
    node. ``token`` goes into every command. ClaimError when the bridge refuses the claim."""

    def __init__(self, node: Any, bridge: str = "/ff_hwbridge", lease: float = 0.0,
                 timeout: float = 10.0, renew: bool = True) -> None:
        self.node, self.bridge, self.timeout = node, bridge, timeout
        # One client for the claim, its renewals and its release: a client created per call must
        # be discovered anew each time, and a response sent before the bridge has matched the new
        # client's reader is lost (the renewal then never arrives and the lease runs out).
        self._cli = node.create_client(ClaimDrive, f"{bridge.rstrip('/')}/claim")
        try:
            if not self._cli.wait_for_service(timeout_sec=timeout):
                raise ClaimError(f"service {bridge}/claim is not available (is the bridge configured?)")
            res = _claim_until_answered(self._cli, node.get_fully_qualified_name(), lease, timeout,
                                        f"{bridge}/claim")
            if not res.success:
                raise ClaimError(f"claim refused: {res.message}")
        except BaseException:
            node.destroy_client(self._cli)
            raise
        self.token: str = res.token
        self.lease: float = float(res.lease)
        self.lost = ""                       # why a renewal failed ("" = still held)
        self._lock = threading.Lock()
        self._timer: Optional[Any] = None
        if renew:
            self._timer = node.create_timer(self.lease / 3.0, self._renew)

    def _renew(self) -> None:
        if self.lost or not self._cli.service_is_ready():
            return
        fut = self._cli.call_async(ClaimDrive.Request(action=ClaimDrive.Request.RENEW, token=self.token))
        fut.add_done_callback(self._renewed)

    def _renewed(self, fut: Any) -> None:
        res = fut.result()
        if res is not None and not res.success:
            self.lost = res.message

    def owner_command(self, command: int) -> Any:
        """FAULT_RESET or ENABLE (ff_msgs/srv/OwnerCommand) as the owner; the response."""
        return owner_command(self.node, self.bridge, command, self.token, self.timeout)

    def release(self) -> Any:
        """Stop renewing and release the claim; the response (success False if already gone)."""
        if self._timer is not None:
            self.node.destroy_timer(self._timer)
            self._timer = None
        try:
            return _wait(self._cli.call_async(ClaimDrive.Request(action=ClaimDrive.Request.RELEASE,
                                                                 token=self.token)),
                         self.timeout, f"{self.bridge}/claim")
        finally:
            self.node.destroy_client(self._cli)
