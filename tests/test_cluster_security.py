"""The local Dask cluster of ``fit-sequence`` is not open to the machine: it speaks TLS
with a certificate made for the run, listens on 127.0.0.1 only, and a client without the
run's credentials cannot connect (so cannot run code on its workers); a ``tls://``
scheduler is reached with the credentials named in a ``--scheduler-security`` file."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def local_cluster():
    from bubblefit.inverse import local_cluster

    client, cluster = local_cluster(1)
    try:
        yield client, cluster
    finally:
        client.close()
        cluster.close()


def test_only_the_runs_client_can_connect(local_cluster, tmp_path):
    from distributed import Client, Security

    client, cluster = local_cluster
    address = cluster.scheduler_address
    assert address.startswith("tls://127.0.0.1:")
    assert all(w.startswith("tls://127.0.0.1:") for w in client.scheduler_info()["workers"])
    assert list(client.run(lambda: 7).values()) == [7]
    marker = tmp_path / "ran"

    def payload():
        marker.write_text("ran")

    attempts = [(address.replace("tls://", "tcp://"), None),  # plain TCP
                (address, None),  # TLS without credentials
                (address, Security.temporary())]  # TLS with another run's certificate
    for target, security in attempts:
        with pytest.raises((OSError, TimeoutError, TypeError)):
            other = Client(target, timeout=3, security=security)
            try:
                other.run(payload)
            finally:
                other.close()
    assert not marker.exists()


def test_a_tls_scheduler_is_reached_with_a_security_file(local_cluster, tmp_path):
    """The credentials written to files and named in a TOML file (as ``--scheduler-security``
    reads it) reach the scheduler; a tcp:// address with a security file is refused."""
    from bubblefit.errors import InputError
    from bubblefit.inverse import SchedulerAddress, start_client

    client, cluster = local_cluster
    sec = client.security
    for name in ("tls_ca_file", "tls_client_cert", "tls_client_key"):
        (tmp_path / f"{name}.pem").write_text(getattr(sec, name))
    (tmp_path / "sec.toml").write_text("\n".join(f'{n} = "{n}.pem"' for n in
                                                 ("tls_ca_file", "tls_client_cert", "tls_client_key")))
    other, none, addrs = start_client(SchedulerAddress(cluster.scheduler_address, str(tmp_path / "sec.toml")), None)
    try:
        assert none is None and addrs == sorted(client.scheduler_info()["workers"])
        assert list(other.run(lambda: 3).values()) == [3]
    finally:
        other.close()
    with pytest.raises(InputError, match="needs a tls:// scheduler"):
        start_client(SchedulerAddress(cluster.scheduler_address.replace("tls://", "tcp://"),
                                       str(tmp_path / "sec.toml")), None)
    (tmp_path / "bad.toml").write_text('tls_ca_file = "missing.pem"\ntls_client_cert = "x.pem"\n')
    with pytest.raises(InputError, match="is not a file"):
        start_client(SchedulerAddress(cluster.scheduler_address, str(tmp_path / "bad.toml")), None)
