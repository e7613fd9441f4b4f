"""The sweep's local dask cluster refuses clients without its credentials.

A plain dask scheduler runs code for any local process that connects; ``fabric_optics.sweep.cluster`` puts the
local cluster behind mutual TLS with temporary credentials. These tests connect as an outsider
would: a raw TLS handshake without a client certificate, a dask client without security, and one
with *other* temporary credentials; each must be refused, while the sweep's own client computes.
"""

from __future__ import annotations

import socket
import ssl

import pytest

from fabric_optics.sweep.cluster import ClusterError, local_cluster, remote_client


@pytest.fixture(scope="module")
def cluster():
    client, cl = local_cluster(1)
    yield client, cl
    client.close()
    cl.close()


def test_own_client_runs_tasks_over_tls(cluster):
    client, cl = cluster
    assert cl.scheduler_address.startswith("tls://127.0.0.1:")
    assert client.submit(lambda x: x + 1, 41).result(timeout=60) == 42


def test_http_server_serves_nothing(cluster):
    """The dashboard and the scheduler's HTTP routes (info, json, proxy) answer 404 without credentials."""
    import urllib.error
    import urllib.request

    _, cl = cluster
    port = cl.scheduler.http_server.port if hasattr(cl.scheduler.http_server, "port") else None
    if port is None:
        port = next(iter(cl.scheduler.http_server._sockets.values())).getsockname()[1]
    for path in ("/status", "/info/main/workers.html", "/json/identity.json", "/health", "/metrics"):
        with pytest.raises(urllib.error.HTTPError) as err:
            urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10)
        assert err.value.code == 404, path


def test_handshake_without_client_certificate_is_refused(cluster):
    _, cl = cluster
    host, port = cl.scheduler_address.split("://", 1)[1].rsplit(":", 1)
    ctx = ssl.create_default_context()
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    with socket.create_connection((host, int(port)), timeout=10) as raw:
        with pytest.raises((ssl.SSLError, ConnectionError, OSError)):
            with ctx.wrap_socket(raw) as tls:
                tls.sendall(b"\x00" * 16)
                # TLS 1.3 reports the missing certificate on the first read
                if not tls.recv(16):
                    raise ConnectionError("closed")


def _connect(address, security, seconds=30.0):
    """Open a dask comm to ``address`` and exchange dask's handshake, as any client does first.

    ``distributed.comm.connect`` retries a failed handshake until its timeout; ``asyncio.wait_for``
    bounds the whole attempt, so a refusal can never hang the suite (a ``Client`` could, under load).
    """
    import asyncio

    from distributed.comm import connect

    async def attempt():
        kwargs = security.get_connection_args("client") if security is not None else {}
        comm = await asyncio.wait_for(connect(address, timeout=seconds, **kwargs), seconds + 15)
        await comm.close()

    asyncio.run(attempt())


def test_client_without_or_with_other_credentials_is_refused(cluster):
    from distributed.security import Security

    client, cl = cluster
    _connect(cl.scheduler_address, client.security)                  # the sweep's own credentials connect
    plain = cl.scheduler_address.replace("tls://", "tcp://")
    with pytest.raises(OSError):                                       # dask's protocol without TLS: reset
        _connect(plain, None)
    with pytest.raises(OSError, match="certificate"):                  # another throw-away CA
        _connect(cl.scheduler_address, Security.temporary())


def test_remote_client_rules():
    with pytest.raises(ClusterError, match="all three"):
        remote_client("tls://127.0.0.1:1", ca_file="ca.pem")
    with pytest.raises(ClusterError, match="tls://"):
        remote_client("tcp://127.0.0.1:1", ca_file="a", cert="b", key="c")
    with pytest.raises(ClusterError, match="unsupported scheme"):
        remote_client("ws://127.0.0.1:1")
