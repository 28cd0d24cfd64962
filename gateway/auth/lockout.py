"""The failed-login lockout as every door applies it: OPC UA, the web console, the FTP inbox.

One `LoginLimiter` (gateway/auth/ratelimit.py) per gateway process, shared by all the
doors, so that guesses on one door count against the others from the same address: an
attacker gets `lockout.failures` guesses per address in all, not that many per door.
These two calls are what a door does around its own password check; both log, never
with the password.
"""

from __future__ import annotations

import logging

from gateway.auth.ratelimit import LoginLimiter

log = logging.getLogger("gateway.auth")


def locked_out(limiter: LoginLimiter, name: str, address: str, via: str) -> float:
    """Seconds `address` is still locked out (0.0: check its password). Logged when it is."""
    wait = limiter.locked(address)
    if wait > 0:
        log.info(
            "%s: login as %r from %s refused unchecked: locked out for %.0f s more",
            via,
            name[:64],
            address,
            wait,
        )
    return wait


def login_failed(limiter: LoginLimiter, name: str, address: str, via: str, why: str) -> None:
    """Count a refused login of `address` (`why`: wrong password, unknown user); logged."""
    if limiter.failed(address):
        log.warning(
            "%s: login as %r from %s refused (%s); %d failures within %.0f s: "
            "refusing every login from %s for %.0f s",
            via,
            name[:64],
            address,
            why,
            limiter.failures,
            limiter.window,
            address,
            limiter.lockout,
        )
    else:
        log.warning("%s: login as %r from %s refused (%s)", via, name[:64], address, why)
