"""Where a library build runs when it uses an existing Dask scheduler: the address, its TLS
certificates, and the connection.

A Dask scheduler runs whatever pickled functions its clients send, and the client unpickles what
the workers send back: whoever can talk to the scheduler can run code on the workers, and whoever
can pose as the scheduler can run code on the client. ``tls://`` with a certificate for each side,
signed by the cluster's own CA (mutual TLS, ``distributed.Security``), limits both to holders of
such a certificate; a plain ``tcp://`` scheduler limits nothing (:meth:`SchedulerSettings.warning`).

``distributed`` is imported only to connect, so that parsing and checking need no Dask.

No ROS here.
"""
from __future__ import annotations

import ssl
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional

SCHEMES = ("tcp", "tls")
TLS_KEYS = ("tls_ca_file", "tls_cert", "tls_key")
CONFIG_KEYS = ("scheduler", *TLS_KEYS)
DEFAULT_CONNECT_TIMEOUT = 30.0      # s, to reach the scheduler (distributed retries within it)
DEFAULT_WORKER_WAIT = 120.0         # s, for a cluster's first worker before a build gives up


class ClusterError(ValueError):
    """A scheduler address or certificate set that cannot be used, or a refused connection; the
    message says what to change."""


class _EncryptedKey(Exception):
    """Raised instead of asking for a passphrase on the terminal."""


def _no_password() -> str:
    raise _EncryptedKey


def _option(key: str) -> str:
    return "--" + key.replace("_", "-")


@dataclass(frozen=True)
class SchedulerAddress:
    """A parsed scheduler address: scheme (tcp or tls), host, port."""

    scheme: str
    host: str
    port: int

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{host}:{self.port}"


def parse_address(text: str) -> SchedulerAddress:
    """``tcp://HOST:PORT``, ``tls://HOST:PORT`` or ``HOST:PORT`` (tcp, as Dask reads it); IPv6
    hosts in brackets. Raises ClusterError."""
    raw = str(text).strip()
    scheme, sep, rest = raw.partition("://")
    if not sep:
        scheme, rest = "tcp", raw
    scheme = scheme.lower()
    if scheme not in SCHEMES:
        raise ClusterError(f"scheduler {raw!r}: scheme {scheme!r} is not supported; use tls://HOST:PORT "
                           f"(or tcp://HOST:PORT, unencrypted)")
    if rest.startswith("["):
        host, close, tail = rest[1:].partition("]")
        port_text = tail[1:] if close and tail.startswith(":") else ""
    else:
        host, _, port_text = rest.rpartition(":")
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not host or not 0 < port < 65536 or "/" in host:
        raise ClusterError(f"scheduler {raw!r}: expected {scheme}://HOST:PORT with a port in 1..65535")
    return SchedulerAddress(scheme, host, port)


@dataclass(frozen=True)
class SchedulerSettings:
    """An existing Dask scheduler to build on, and this client's TLS files (PEM): the CA that
    signed the cluster's certificates, and this client's certificate and key."""

    address: str
    tls_ca_file: Optional[str] = None
    tls_cert: Optional[str] = None
    tls_key: Optional[str] = None

    @property
    def parsed(self) -> SchedulerAddress:
        return parse_address(self.address)

    @property
    def uses_tls(self) -> bool:
        return self.parsed.scheme == "tls"

    def check(self) -> None:
        """Raise ClusterError unless the address parses, a ``tls://`` address has all three files
        (readable, the key matching the certificate) and a ``tcp://`` one has none."""
        addr = self.parsed
        given = [k for k in TLS_KEYS if getattr(self, k)]
        if addr.scheme == "tcp" and given:
            raise ClusterError(f"{', '.join(_option(k) for k in given)} given, but the scheduler address "
                               f"{addr.url} is plain tcp://; use tls://{addr.url.split('://', 1)[1]}")
        if addr.scheme != "tls":
            return
        missing = [k for k in TLS_KEYS if not getattr(self, k)]
        if missing:
            raise ClusterError(f"the tls:// scheduler {addr.url} needs {', '.join(_option(k) for k in missing)} "
                               f"(the cluster's CA, and this client's certificate and key signed by it)")
        for k in TLS_KEYS:
            p = Path(str(getattr(self, k))).expanduser()
            if not p.is_file():
                raise ClusterError(f"{_option(k)}: no file at {p}")
        self._context()

    def _context(self) -> ssl.SSLContext:
        """A client context from the three files (raises ClusterError naming the bad file)."""
        ca, cert, key = (str(Path(str(getattr(self, k))).expanduser()) for k in TLS_KEYS)
        ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH)
        try:
            ctx.load_verify_locations(cafile=ca)
        except (ssl.SSLError, OSError) as exc:
            raise ClusterError(f"--tls-ca-file {ca}: not a PEM CA certificate ({exc})") from None
        try:
            ctx.load_cert_chain(cert, key, password=_no_password)
        except _EncryptedKey:
            raise ClusterError(f"--tls-key {key}: the key is encrypted; Dask reads keys without a "
                               f"passphrase (decrypt it into a file only this user can read)") from None
        except (ssl.SSLError, OSError) as exc:
            raise ClusterError(f"--tls-cert {cert} / --tls-key {key}: not a PEM certificate and its "
                               f"matching key ({exc})") from None
        return ctx

    def security(self) -> Any:
        """The ``distributed.Security`` for this client (encryption required), or None for tcp://."""
        if not self.uses_tls:
            return None
        from distributed import Security

        ca, cert, key = (str(Path(str(getattr(self, k))).expanduser()) for k in TLS_KEYS)
        return Security(tls_ca_file=ca, tls_client_cert=cert, tls_client_key=key, require_encryption=True)

    def warning(self) -> Optional[str]:
        """One line for a plain tcp:// scheduler (unencrypted, unauthenticated); None for tls://."""
        addr = self.parsed
        if addr.scheme == "tls":
            return None
        return (f"the Dask scheduler {addr.url} is plain tcp://: unencrypted and unauthenticated; "
                f"whoever reaches it can run code on its workers and hand this build its results. "
                f"Use tls:// with --tls-ca-file, --tls-cert, --tls-key (docs/security.md)")


def settings_from_mapping(data: Mapping[str, Any], base_dir: Optional[Path] = None) -> Optional[SchedulerSettings]:
    """The scheduler keys of a grid file (``scheduler``, ``tls_ca_file``, ``tls_cert``, ``tls_key``);
    relative file names are taken from ``base_dir`` (the grid file's folder). None without
    ``scheduler``; raises ClusterError when TLS files are given without it or a value is not text."""
    values: dict[str, Optional[str]] = {}
    for k in CONFIG_KEYS:
        v = data.get(k)
        if v is None:
            values[k] = None
            continue
        if not isinstance(v, str) or not v.strip():
            raise ClusterError(f"{k}: expected text (an address or a file name), got {v!r}")
        values[k] = v.strip()
    if values["scheduler"] is None:
        extra = [k for k in TLS_KEYS if values[k]]
        if extra:
            raise ClusterError(f"{', '.join(extra)} given without scheduler: add scheduler: tls://HOST:PORT")
        return None
    for k in TLS_KEYS:
        v = values[k]
        if v is not None and base_dir is not None:
            p = Path(v).expanduser()
            values[k] = str(p if p.is_absolute() else Path(base_dir) / p)
    return SchedulerSettings(str(values["scheduler"]), values["tls_ca_file"], values["tls_cert"],
                             values["tls_key"])


def merge(base: Optional[SchedulerSettings], address: Optional[str] = None, tls_ca_file: Optional[str] = None,
          tls_cert: Optional[str] = None, tls_key: Optional[str] = None) -> Optional[SchedulerSettings]:
    """``base`` (from a grid file) with the given values replacing its own, one by one; None when
    no address results (TLS files without an address raise ClusterError)."""
    addr = address or (base.address if base else None)
    files = {k: v or (getattr(base, k) if base else None)
             for k, v in zip(TLS_KEYS, (tls_ca_file, tls_cert, tls_key))}
    if addr is None:
        given = [k for k, v in files.items() if v]
        if given:
            raise ClusterError(f"{', '.join(_option(k) for k in given)} apply to --scheduler tls://HOST:PORT; "
                               f"give the scheduler too")
        return None
    return SchedulerSettings(addr, **files)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def connect(settings: SchedulerSettings, timeout: float = DEFAULT_CONNECT_TIMEOUT) -> Any:
    """A ``distributed.Client`` on the scheduler, after :meth:`SchedulerSettings.check`. Raises
    ClusterError when it cannot be reached or refuses this client (a certificate it does not trust,
    a plain connection to a TLS port)."""
    settings.check()
    from distributed import Client

    addr = settings.parsed
    try:
        return Client(addr.url, security=settings.security(), timeout=timeout)
    except (OSError, TypeError, ValueError, ssl.SSLError) as exc:   # CommClosedError is an OSError
        reason = _one_line(exc)
        if addr.scheme == "tls":
            raise ClusterError(
                f"the Dask scheduler {addr.url} refused this client or could not be reached ({reason}); check "
                f"that it runs, that --tls-cert and --tls-key are signed by the cluster's CA and that "
                f"--tls-ca-file is that CA") from None
        raise ClusterError(f"cannot use the Dask scheduler at {addr.url} ({reason}); check the address and "
                           f"that it runs (a TLS scheduler needs tls:// and certificates)") from None


def wait_for_workers(client: Any, address: str, timeout: float = DEFAULT_WORKER_WAIT) -> int:
    """Block until the scheduler behind ``client`` has at least one worker; returns how many it
    has. Raises ClusterError after ``timeout`` s (a scheduler without workers would otherwise hold
    a build forever, its tasks queued)."""
    if timeout <= 0:
        raise ClusterError(f"the worker wait must be > 0 s, got {timeout}")
    try:
        client.wait_for_workers(1, timeout=timeout)
    except (TimeoutError, OSError) as exc:
        raise ClusterError(f"the Dask scheduler {address} has no workers after {timeout:g} s "
                           f"({_one_line(exc)}); start some with 'dask worker {address} ...' "
                           f"(docs/security.md) or raise --worker-wait") from None
    return len(client.scheduler_info().get("workers", {}))
