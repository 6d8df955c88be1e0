"""Who may command a drive group: claims, leases and refusals (plain Python, no ROS)."""
from ff_hwbridge.ownership.claims import (COMMAND_KINDS, Claim, ClaimRefused, Decision, Ownership,
                                          qualified_name)

__all__ = ["COMMAND_KINDS", "Claim", "ClaimRefused", "Decision", "Ownership", "qualified_name"]
