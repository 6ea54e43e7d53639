"""The quick SLURM probe of tests/conftest.py: a controller port that refuses connections
means SLURM is not running (skip at once instead of `sinfo`'s ~9 s of retries); a port
that accepts, or a slurm.conf that names no controller, leaves the decision to `sinfo`."""
from __future__ import annotations

import socket

from tests.conftest import _controller_refuses


def _conf(tmp_path, text: str) -> str:
    p = tmp_path / "slurm.conf"
    p.write_text(text)
    return str(p)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]          # closed again when the block ends


def test_a_refusing_controller_port_is_named(tmp_path):
    port = _closed_port()
    conf = _conf(tmp_path, f"ClusterName=ci\nSlurmctldHost=vm(127.0.0.1)  # comment\n"
                           f"SlurmctldPort={port}-{port + 1}\n")
    assert _controller_refuses(conf) == f"127.0.0.1:{port}"
    conf = _conf(tmp_path, f"ControlMachine=127.0.0.1\nSlurmctldPort={port}\n")
    assert _controller_refuses(conf) == f"127.0.0.1:{port}"


def test_a_listening_controller_or_an_unreadable_conf_defers_to_sinfo(tmp_path):
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        port = srv.getsockname()[1]
        assert _controller_refuses(_conf(tmp_path, f"SlurmctldHost=127.0.0.1\n"
                                                   f"SlurmctldPort={port}\n")) is None
    assert _controller_refuses(_conf(tmp_path, "# SlurmctldHost=127.0.0.1\nClusterName=x\n")) is None
    assert _controller_refuses(str(tmp_path / "missing.conf")) is None
