"""The dask clusters of ``simulate sweep``: mutual TLS, so that nobody else on the machine can run code.

A dask scheduler executes whatever a connected client submits, as the user who started the
workers. A plain ``tcp://127.0.0.1`` scheduler therefore runs code for *any* local process that
finds its port. The rules here:

- **Local cluster** (the default): :func:`local_cluster` starts the ``LocalCluster`` on
  ``tls://127.0.0.1`` with :meth:`distributed.security.Security.temporary` - a throw-away CA and
  certificate that exist only in this process's memory and are handed to the workers it spawns.
  The scheduler requires a client certificate signed by that CA (``require_encryption``): a client
  without it fails the TLS handshake, and one with other credentials fails verification. The
  dashboard is off, and the scheduler's HTTP
  server serves no route (it has no authentication).
- **A running scheduler** (``--scheduler``): :func:`remote_client` connects with the user's TLS
  files (``--tls-ca-file``, ``--tls-cert``, ``--tls-key``) or, without them, with dask's own
  configuration (``distributed.comm.tls.*``, e.g. ``DASK_DISTRIBUTED__COMM__TLS__CA_FILE``), as
  distributed's documentation describes (https://distributed.dask.org/en/stable/tls.html).
  A ``tcp://`` address is accepted for clusters the user secures otherwise (a private network),
  with a warning that plain TCP is unauthenticated.

Requires the ``cryptography`` package (pinned in pyproject.toml) for the temporary credentials.
"""

from __future__ import annotations

import logging
import warnings
from typing import Any

__all__ = ["ClusterError", "local_cluster", "remote_client"]

log = logging.getLogger(__name__)


class ClusterError(ValueError):
    """A cluster or scheduler the sweep cannot use (the message says which and why)."""


def local_cluster(workers: int) -> tuple[Any, Any]:
    """``(client, cluster)``: a new local cluster of ``workers`` processes behind mutual TLS."""
    import dask
    from distributed import Client, LocalCluster
    from distributed.security import Security

    security = Security.temporary()
    # the scheduler always runs an HTTP server; with no routes it answers 404 to everything
    # (dashboard, /info, /json, the proxy to the workers): nothing readable without credentials
    no_http: dict[str, list[str]] = {"distributed.scheduler.http.routes": [], "distributed.worker.http.routes": []}
    with warnings.catch_warnings(), dask.config.set(no_http):
        # the scheduler's HTTP server moves to a free port when 8787 is taken: nothing to tell
        warnings.filterwarnings("ignore", message="Port .* is already in use")
        # processes, one thread each: the kernels hold the GIL in places and numba's threads are
        # set per task (--threads); no dashboard: it has no authentication
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, security=security, protocol="tls://",
                               host="127.0.0.1")
    return Client(cluster, security=security), cluster


def remote_client(address: str, *, ca_file: str | None = None, cert: str | None = None,
                  key: str | None = None, timeout: str = "20s") -> Any:
    """A client of the scheduler at ``address`` with the user's TLS files (or dask's TLS config)."""
    from distributed import Client
    from distributed.security import Security

    scheme = address.split("://", 1)[0] if "://" in address else "tcp"
    given = [f for f in (ca_file, cert, key) if f]
    if given and len(given) != 3:
        raise ClusterError("--scheduler: give all three of --tls-ca-file, --tls-cert and --tls-key (or none, "
                           "to use dask's distributed.comm.tls configuration)")
    if scheme == "tcp":
        if given:
            raise ClusterError(f"--scheduler {address}: TLS files given for a tcp:// address; use tls://HOST:PORT")
        log.warning("--scheduler %s: plain TCP is unauthenticated: anyone who can reach the scheduler can run "
                    "code on its workers (use tls:// with certificates)", address)
        security = None
    elif scheme == "tls":
        security = (Security(tls_ca_file=ca_file, tls_client_cert=cert, tls_client_key=key,
                             require_encryption=True) if given else Security())
    else:
        raise ClusterError(f"--scheduler {address}: unsupported scheme {scheme!r} (use tls://HOST:PORT)")
    try:
        return Client(address, security=security, timeout=timeout)
    except (OSError, TimeoutError, ValueError, TypeError) as exc:
        raise ClusterError(f"--scheduler {address}: cannot connect ({exc})") from None
